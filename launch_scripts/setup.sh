#!/usr/bin/env bash
# Idempotent set-up: Debian packages the wheels need (libusb for open3d; pocl where pip's pocl
# cannot compile for this CPU), a virtual environment at .venv with the pinned dependencies, this
# package installed in editable mode, and the interface packages under msg_defs/ (one folder per
# package: nbv_prob_cnn_msgs, tf2_msgs, ...) built into the environment by build_interfaces.sh.
# Fast when nothing changed (a stamp file records the hash of the inputs).
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$repo"
venv="$repo/.venv"
stamp="$venv/.nbv_setup_stamp"
want="$(cat requirements.txt setup.py launch_scripts/setup.sh | sha256sum | cut -d' ' -f1)"

# Debian packages the wheels need (apt, with sudo unless root).
apt_install() {
  local sudo=""
  [ "$(id -u)" -ne 0 ] && sudo="sudo"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "$@" >/dev/null
}

# The OpenCL kernels need a device that compiles them. pip's pocl (pyopencl[pocl]) fails on CPUs
# its LLVM does not know ("unknown target CPU 'generic'", e.g. some virtualised AMD EPYC); then the
# Debian build of pocl (pocl-opencl-icd), which the bundled ICD loader also finds, is installed.
probe_opencl() { "$venv/bin/python" -c "from nbv_prob_cnn.basics.cl_device import cl_runtime; cl_runtime()" 2>"$venv/.nbv_opencl.log"; }
ensure_opencl() {
  if ! probe_opencl; then
    echo "[setup] no OpenCL device compiles kernels with pip's pocl; installing Debian's pocl-opencl-icd"
    apt_install pocl-opencl-icd
    probe_opencl || { tail -5 "$venv/.nbv_opencl.log"; echo "[setup] no usable OpenCL device"; exit 1; }
  fi
}

if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
  VIRTUAL_ENV="$venv" bash "$repo/launch_scripts/build_interfaces.sh"
  ensure_opencl
  exit 0
fi

# open3d-cpu links against libusb-1.0 (Debian package libusb-1.0-0).
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  echo "[setup] installing libusb-1.0-0 (needed by open3d)"
  apt_install libusb-1.0-0
fi

if [ ! -x "$venv/bin/python" ]; then
  echo "[setup] creating virtual environment $venv"
  python3 -m venv "$venv"
fi
echo "[setup] installing pinned dependencies (requirements.txt)"
"$venv/bin/python" -m pip install -q --disable-pip-version-check -r requirements.txt
"$venv/bin/python" -m pip install -q --disable-pip-version-check --no-deps -e . 2>"$venv/.nbv_install.log" \
  || { cat "$venv/.nbv_install.log"; exit 1; }
VIRTUAL_ENV="$venv" bash "$repo/launch_scripts/build_interfaces.sh"

ensure_opencl
echo "$want" > "$stamp"
echo "[setup] done"
