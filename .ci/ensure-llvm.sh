#!/usr/bin/env bash
# Make sure a libLLVM usable by Dr.Jit 1.5 is installed (LLVM 14-16 abort it).
# Usage: ensure-llvm.sh PYTHON
set -euo pipefail
py="$1"
check() { "$py" -c 'import sys; from mitsuba_whitted import llvm
try: print("libLLVM:", llvm.select().path)
except llvm.LLVMError as e: print(e, file=sys.stderr); sys.exit(1)' ; }
check 2>/dev/null && exit 0
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    echo "No usable libLLVM found: installing libllvm19 with apt-get"
    apt-get update -qq >/dev/null
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null
elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
    echo "No usable libLLVM found: installing libllvm19 with sudo apt-get"
    sudo apt-get update -qq >/dev/null
    sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null
fi
check
