#!/usr/bin/env bash
# Make sure a libLLVM usable by Dr.Jit 1.5 is installed (LLVM 14-16 abort it).
# Usage: ensure-llvm.sh PYTHON
set -euo pipefail
py="$1"
check() { "$py" -c 'import sys; from mitsuba_whitted import llvm
try: print("libLLVM:", llvm.select().path)
except llvm.LLVMError as e: print(e, file=sys.stderr); sys.exit(1)' ; }
check 2>/dev/null && exit 0
echo "No usable libLLVM found"
"$(dirname "$0")/apt-install.sh" libllvm19
check
