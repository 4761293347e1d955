#!/usr/bin/env bash
# Idempotent set-up: system packages for headless rendering and video, a Python 3.12
# virtual environment in .venv with the project installed editable. Fast when done:
# the venv is reinstalled only when pyproject.toml changes.
set -euo pipefail
cd "$(dirname "$0")/.."
say() { printf '[setup] %s\n' "$*"; }

# --- system packages (Debian 12): lavapipe >= 24.3 from bookworm-backports, ffmpeg ---------
mesa_ok() {
  local v
  v=$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true)
  [ -n "$v" ] && dpkg --compare-versions "$v" ge 24.3
}
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  need=()
  mesa_ok || need+=(mesa)
  command -v ffmpeg >/dev/null 2>&1 || need+=(ffmpeg)
  if [ ${#need[@]} -gt 0 ]; then
    say "installing system packages: ${need[*]} (Vulkan lavapipe for headless rendering, ffmpeg for video)"
    if grep -q bookworm /etc/os-release 2>/dev/null && ! grep -rqs bookworm-backports /etc/apt/sources.list /etc/apt/sources.list.d/; then
      say "adding bookworm-backports to apt sources (Mesa >= 24.3 lives there)"
      printf 'Types: deb\nURIs: http://deb.debian.org/debian\nSuites: bookworm-backports\nComponents: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n' \
        > /etc/apt/sources.list.d/bookworm-backports.sources
    fi
    apt-get update -qq
    pkgs=(ffmpeg libvulkan1)
    if grep -q bookworm /etc/os-release 2>/dev/null; then
      DEBIAN_FRONTEND=noninteractive apt-get install -y -qq -t bookworm-backports mesa-vulkan-drivers >/dev/null
    else
      pkgs+=(mesa-vulkan-drivers)
    fi
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${pkgs[@]}" >/dev/null
  fi
else
  mesa_ok || say "WARNING: cannot install Mesa lavapipe >= 24.3 (need root + apt); rendering may be unavailable"
fi

# --- Python 3.12 venv ------------------------------------------------------------------
PY=${PRL_PYTHON:-}
if [ -z "$PY" ]; then
  for c in python3.12 "$HOME/.pyenv/versions/3.12.1/bin/python" /root/.pyenv/versions/3.12*/bin/python; do
    if command -v "$c" >/dev/null 2>&1 && "$c" -c 'import sys; assert sys.version_info[:2]==(3,12)' 2>/dev/null; then PY=$c; break; fi
  done
fi
if [ ! -x .venv/bin/python ]; then
  [ -n "$PY" ] || { echo "[setup] ERROR: Python 3.12 not found; set PRL_PYTHON=/path/to/python3.12" >&2; exit 1; }
  say "creating .venv with $PY"
  "$PY" -m venv .venv
fi
stamp=.venv/.prl-setup-stamp
want=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null || true)" != "$want" ]; then
  say "installing the project and its dependencies into .venv (several GB the first time)"
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -e '.[dev]'
  echo "$want" > "$stamp"
else
  say "environment up to date"
fi
