#!/usr/bin/env bash
# Build the interface package msg_defs/ (nbv_prob_cnn_msgs) with ament_cmake from the ROS
# wheels and install it into the virtual environment. Called by setup.sh; idempotent.
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${VIRTUAL_ENV:-$repo/.venv}"
py="$venv/bin/python"
stamp="$venv/.nbv_msgs_stamp"
want="$( (find "$repo/msg_defs" -type f | sort | xargs cat; cat "$0") | sha256sum | cut -d' ' -f1)"
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && "$py" -c "import nbv_prob_cnn_msgs.msg" 2>/dev/null; then
  exit 0
fi

# The wheels' exported cmake files name the include dirs of the machine that built them.
py_inc="$("$py" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')"
np_inc="$("$py" -c 'import numpy; print(numpy.get_include())')"
{ grep -rl "/opt/python/cp311-cp311" "$venv/share" --include='*.cmake' 2>/dev/null || true; } | while read -r f; do
  sed -i -e "s|/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include|$np_inc|g" \
         -e "s|/opt/python/cp311-cp311/include/python3.11|$py_inc|g" "$f"
done

export AMENT_PREFIX_PATH="$venv"
export CMAKE_PREFIX_PATH="$venv"
export PATH="$venv/bin:$PATH"
build="$repo/build/msgs"
mkdir -p "$repo/build"
echo "[setup] building interfaces msg_defs/ -> nbv_prob_cnn_msgs"
cmake -S "$repo/msg_defs" -B "$build" -DCMAKE_INSTALL_PREFIX="$venv" -DBUILD_TESTING=OFF \
  -DPython3_EXECUTABLE="$py" -DPYTHON_EXECUTABLE="$py" >"$build.log" 2>&1 \
  || { tail -40 "$build.log"; exit 1; }
cmake --build "$build" -j 2 >>"$build.log" 2>&1 || { tail -40 "$build.log"; exit 1; }
cmake --install "$build" >>"$build.log" 2>&1 || { tail -40 "$build.log"; exit 1; }
"$py" -c "import nbv_prob_cnn_msgs.msg, nbv_prob_cnn_msgs.srv, nbv_prob_cnn_msgs.action" \
  || { echo "[setup] nbv_prob_cnn_msgs was built but does not import"; exit 1; }
echo "$want" > "$stamp"
