#!/usr/bin/env bash
# Idempotent set-up for a fresh Debian 12 machine (docs/design.md §14):
#   1. Mesa 25 lavapipe (software Vulkan) from Debian's bookworm-backports suite, which SAPIEN needs;
#   2. a virtualenv at .venv in the repository root;
#   3. torch 2.13.0 (local CPU wheel) *before* anything that depends on torch;
#   4. this package with its dev, distributed and track extras (mani-skill, sapien, rerun-sdk, pybullet, pytest,
#      ruff; Ray, which the tests of the Ray backend and sweeps need: docs/distributed.md; TensorBoard, which
#      the DQN's --track and its test need).
# Each step is skipped when already done. Fails with a clear message when something cannot be installed.
set -euo pipefail
cd "$(dirname "$0")/.."
say() { printf '[setup] %s\n' "$*"; }
die() { printf '[setup] ERROR: %s\n' "$*" >&2; exit 1; }

SUDO=""
[ "$(id -u)" = 0 ] || SUDO="sudo"

have_mesa25() {
  dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null | grep -qE '^(2[5-9]|[3-9][0-9])\.'
}

if have_mesa25 && dpkg-query -W libvulkan1 >/dev/null 2>&1; then
  say "Mesa >= 25 Vulkan drivers already installed"
else
  command -v apt-get >/dev/null || die "apt-get not found: this set-up supports Debian 12 only (install Mesa >= 25 Vulkan drivers by hand)"
  list=/etc/apt/sources.list.d/bookworm-backports.sources
  if ! grep -rqs 'bookworm-backports' /etc/apt/sources.list /etc/apt/sources.list.d/; then
    # Derive the entry from the machine's own Debian sources: same URI and keyring, suite bookworm-backports.
    uri=$(awk '/^URIs:/ {u=$2} /^Suites:/ && / bookworm( |$)|: bookworm( |$)/ {print u; exit}' /etc/apt/sources.list.d/*.sources 2>/dev/null || true)
    [ -n "$uri" ] || uri=$(awk '$1=="deb" && $3=="bookworm" {print $2; exit}' /etc/apt/sources.list 2>/dev/null || true)
    [ -n "$uri" ] || die "could not find the Debian 'bookworm' entry in apt's sources to derive bookworm-backports from"
    say "adding apt suite bookworm-backports (from $uri) to $list"
    printf 'Types: deb\nURIs: %s\nSuites: bookworm-backports\nComponents: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n' "$uri" | $SUDO tee "$list" >/dev/null
  fi
  say "installing mesa-vulkan-drivers and libvulkan1 from bookworm-backports (Mesa 25 lavapipe)"
  $SUDO apt-get update -qq || die "apt-get update failed"
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq -t bookworm-backports mesa-vulkan-drivers libvulkan1 >/dev/null \
    || die "could not install mesa-vulkan-drivers/libvulkan1 from bookworm-backports"
  have_mesa25 || die "mesa-vulkan-drivers is not >= 25 after install; SAPIEN refuses older lavapipe"
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  say "creating virtualenv .venv"
  "$PY" -m venv .venv || die "could not create .venv with $PY (needs Python >= 3.10 with venv)"
fi
VPY=.venv/bin/python

if "$VPY" -c 'import torch, sys; sys.exit(0 if torch.__version__.startswith("2.13.0") else 1)' 2>/dev/null; then
  say "torch 2.13.0 already installed"
else
  say "installing torch==2.13.0 (CPU wheel) before anything that depends on torch"
  "$VPY" -m pip install -q torch==2.13.0 || die "could not install torch==2.13.0"
fi

stamp=.venv/.mani-active-vision-installed
if [ -f "$stamp" ] && [ "$stamp" -nt pyproject.toml ]; then
  say "mani-active-vision[dev,distributed,track] already installed"
else
  say "installing mani-active-vision (editable) with dev, distributed and track extras"
  "$VPY" -m pip install -q -e '.[dev,distributed,track]' || die "could not install the package; see pip's message above"
  touch "$stamp"
fi
say "done"
