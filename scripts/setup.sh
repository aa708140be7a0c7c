#!/usr/bin/env bash
# Idempotent installer for the two README commands: system LLVM for Mitsuba's LLVM backend, then a
# virtual environment with the pinned CPU torch first (so nothing pulls CUDA wheels), then the project.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}

# apt_install PACKAGE WHY NOTE: install a Debian package when root; otherwise say how, and what is lost.
apt_install() {
  if [ "$(id -u)" = 0 ]; then
    echo "setup: installing $1 ($2)"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$1" >/dev/null
  else
    echo "setup: $1 is missing and this is not root. Run 'sudo apt-get install -y $1'" >&2
    echo "       $3" >&2
  fi
}

if ! ldconfig -p 2>/dev/null | grep -q 'libLLVM.so.19\|libLLVM-19.so'; then
  apt_install libllvm19 "Mitsuba's llvm_ad_rgb variant needs LLVM >= 16" \
    "(or set DRJIT_LIBLLVM_PATH); until then Mitsuba falls back to the ~45x slower scalar_rgb."
fi

# OpenGL for the client's raster passes (gicore.gl: moderngl on a headless EGL context, no X server):
# the GLVND EGL loader, Mesa's EGL and Mesa's DRI drivers (llvmpipe without a GPU; a GPU's vendor driver
# brings its own EGL library).
if command -v dpkg-query >/dev/null; then
  for pkg in libegl1 libegl-mesa0 libgl1-mesa-dri; do
    if ! dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed"; then
      apt_install "$pkg" "gicore.gl opens a headless EGL OpenGL context through it" \
        "(until then gicore.gl raises RasterUnavailable: clients use Mitsuba; tests/gicore/test_raster.py is skipped)."
    fi
  done
fi

# Chromium for the dashboard's browser test (tests/test_report.py drives it with Playwright).
if [ ! -x /usr/bin/chromium ]; then
  apt_install chromium "the dashboard test opens bench report's HTML in it" \
    "(until then the dashboard's browser test is skipped; under CI=true it fails)."
fi

# The Web3D viewer's JavaScript (onnxruntime-web, fzstd, three) and its type checker (TypeScript, a development
# dependency: --include=dev whatever NODE_ENV says) from web3d/static/package-lock.json, installed while pip works (it
# needs nothing from Python); without npm the viewer, bench web and tests/web3d are unavailable (the tests skip and
# say so).
npm_pid=""
if command -v npm >/dev/null; then
  (cd web3d/static && npm ci --include=dev --no-audit --no-fund --loglevel=error) &
  npm_pid=$!
  trap 'kill "$npm_pid" 2>/dev/null || true' EXIT
else
  echo "setup: npm is missing: the Web3D viewer (gigan-web, bench web) needs Node 20 + npm" >&2
fi

if [ ! -x .venv/bin/python ]; then
  "$PYTHON" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
# --no-compile: pip would compile all ~14,000 modules of the wheels (45 s of a 2-minute install), most of which no
# command imports. The modules the commands do import are compiled once below, and the rest on first import.
.venv/bin/python -m pip install -q --no-compile "torch==2.13.0"
# ray: the optional extra behind --ray (gicore.executor), installed so that its tests run.
.venv/bin/python -m pip install -q --no-compile -e ".[test,ray]"
env -u PYTHONDONTWRITEBYTECODE .venv/bin/python -c \
  "import torch, mitsuba, ray, onnx, onnxruntime, skimage, fastapi, uvicorn, httpx, matplotlib.pyplot, pytest" ||
  echo "setup: importing the dependencies once failed (see above); they are compiled on first use instead" >&2
if [ -n "$npm_pid" ] && ! wait "$npm_pid"; then
  echo "setup: npm ci in web3d/static/ failed: the Web3D viewer is unavailable" >&2
fi
trap - EXIT
echo "setup: done (.venv)"
