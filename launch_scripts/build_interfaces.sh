#!/usr/bin/env bash
# Build every interface package under msg_defs/ (one folder per package, each with its package.xml:
# nbv_prob_cnn_msgs, the wire-compatible tf2_msgs, ...) with ament_cmake from the ROS wheels and
# install it into the virtual environment, in dependency order (catkin_pkg's topological order of
# the package.xml files, so a new folder is picked up without editing this script).
# A package that already imports from outside the virtual environment (a ROS install such as a
# sourced /opt/ros/jazzy, or a workspace overlay) is skipped: the install's own build is used.
# Called by setup.sh; idempotent: a stamp per package records the hash of its folder, of the
# folders of the local packages it depends on, and of this script.
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${VIRTUAL_ENV:-$repo/.venv}"
py="$venv/bin/python"
defs="$repo/msg_defs"

# "<folder> <name> <local dependencies...>" per package, dependencies first.
order="$("$py" - "$defs" <<'EOF'
import sys
from catkin_pkg.topological_order import topological_order

ordered = topological_order(sys.argv[1])
local = {package.name for _, package in ordered}
for path, package in ordered:
    deps = {d.name for d in package.build_depends + package.buildtool_depends + package.exec_depends}
    print(path, package.name, *sorted(deps & local))
EOF
)"
[ -n "$order" ] || { echo "[setup] no interface package (package.xml) under $defs"; exit 1; }

# Where a package imports from, or nothing when it does not import.
module_origin() { "$py" -c "import importlib.util as u, sys; s = u.find_spec(sys.argv[1]); print(s.origin if s and s.origin else '')" "$1" 2>/dev/null || true; }
folder_hash() { (find "$defs/$1" -type f | sort | xargs cat; cat "$0") | sha256sum | cut -d' ' -f1; }

prepared=0
prepare_build() {
  [ "$prepared" = 1 ] && return 0
  # The wheels' exported cmake files name the include dirs of the machine that built them.
  local py_inc np_inc
  py_inc="$("$py" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')"
  np_inc="$("$py" -c 'import numpy; print(numpy.get_include())')"
  { grep -rl "/opt/python/cp311-cp311" "$venv/share" --include='*.cmake' 2>/dev/null || true; } | while read -r f; do
    sed -i -e "s|/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include|$np_inc|g" \
           -e "s|/opt/python/cp311-cp311/include/python3.11|$py_inc|g" "$f"
  done
  export AMENT_PREFIX_PATH="$venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
  export CMAKE_PREFIX_PATH="$venv${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"
  export PATH="$venv/bin:$PATH"
  mkdir -p "$repo/build/interfaces"
  prepared=1
}

declare -A want_of
while read -r folder name deps; do
  want="$( (folder_hash "$folder"; for dep in $deps; do echo "${want_of[$dep]:-}"; done) | sha256sum | cut -d' ' -f1)"
  want_of[$name]="$want"
  origin="$(module_origin "$name")"
  if [ -n "$origin" ] && [ "${origin#"$venv"/}" = "$origin" ]; then
    echo "[setup] $name comes from $(dirname "$(dirname "$origin")"); not building msg_defs/$folder"
    continue
  fi
  stamp="$venv/.nbv_msgs_stamp_$name"
  if [ -n "$origin" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
    continue
  fi
  prepare_build
  build="$repo/build/interfaces/$name"
  echo "[setup] building interfaces msg_defs/$folder -> $name"
  cmake -S "$defs/$folder" -B "$build" -DCMAKE_INSTALL_PREFIX="$venv" -DBUILD_TESTING=OFF \
    -DPython3_EXECUTABLE="$py" -DPYTHON_EXECUTABLE="$py" >"$build.log" 2>&1 \
    || { tail -40 "$build.log"; exit 1; }
  cmake --build "$build" -j 2 >>"$build.log" 2>&1 || { tail -40 "$build.log"; exit 1; }
  cmake --install "$build" >>"$build.log" 2>&1 || { tail -40 "$build.log"; exit 1; }
  kinds="$(cd "$defs/$folder" && ls -d msg srv action 2>/dev/null || true)"
  "$py" -c "import importlib, sys; [importlib.import_module(sys.argv[1] + '.' + kind) for kind in sys.argv[2:]]" \
    "$name" $kinds || { echo "[setup] $name was built but does not import"; exit 1; }
  echo "$want" > "$stamp"
done <<<"$order"
rm -f "$venv/.nbv_msgs_stamp"  # the single stamp of the one-package layout
