#!/usr/bin/env bash
# Make sure Debian's Chromium is installed for the browser tests (Playwright
# drives it through its executable path; its own browser download is not
# used). Without it the browser tests are skipped, saying why.
set -euo pipefail
command -v chromium >/dev/null 2>&1 && exit 0
echo "No chromium found"
"$(dirname "$0")/apt-install.sh" chromium || echo "chromium could not be installed: the browser tests will be skipped"
