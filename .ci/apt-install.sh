#!/usr/bin/env bash
# Install Debian packages where this user may (root, or sudo without a
# password); elsewhere do nothing, and the caller's own check says what is
# missing. Usage: apt-install.sh PACKAGE...
set -euo pipefail
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    as_root=()
elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
    as_root=(sudo)
else
    exit 0
fi
echo "installing $* with apt-get"
"${as_root[@]}" apt-get update -qq >/dev/null
"${as_root[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null
