#!/usr/bin/env bash
# Install the headless browser the report tests use (tests marked `browser`).
#
# Chromium from the Debian system packages; idempotent: does nothing when
# /usr/bin/chromium already exists. Needs root (or sudo) for apt-get. When it
# cannot install (no root, no apt-get) it says so; in CI (CI=true) that is an
# error (exit 1: a CI run must not pass with the browser tests skipped),
# elsewhere it exits 0 and the browser tests skip with a reason.
set -euo pipefail

cannot_install() {
    echo "install-browser: $*" >&2
    if [ "${CI:-}" = "true" ]; then
        echo "install-browser: Chromium is required in CI (CI=true); stopping" >&2
        exit 1
    fi
    exit 0
}

# MAGLEVID_CHROMIUM: the path checked (tests point it elsewhere).
CHROMIUM="${MAGLEVID_CHROMIUM:-/usr/bin/chromium}"

if [ -x "$CHROMIUM" ]; then
    echo "install-browser: $CHROMIUM present ($("$CHROMIUM" --version 2>/dev/null || echo 'version unknown'))"
    exit 0
fi

if ! command -v apt-get >/dev/null 2>&1; then
    cannot_install "apt-get not found; install Chromium by hand to run the browser tests"
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
        SUDO="sudo -n"
    else
        cannot_install "not root and no password-less sudo; browser tests will skip"
    fi
fi

export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
# DejaVu: a font for the page text on minimal images (chromium only recommends fonts).
$SUDO apt-get install -y -qq --no-install-recommends chromium fonts-dejavu-core >/dev/null
if [ ! -x "$CHROMIUM" ]; then
    echo "install-browser: apt-get finished but $CHROMIUM is missing" >&2
    exit 1
fi
echo "install-browser: installed $("$CHROMIUM" --version 2>/dev/null || echo chromium)"
