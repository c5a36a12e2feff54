#!/usr/bin/env bash
# dm_control renders with MuJoCo's OpenGL backend. On a machine with no GPU and no display we use
# OSMesa (software rendering): install it from Debian's packages when it is missing and we are root.
set -u
if ldconfig -p 2>/dev/null | grep -q libOSMesa; then exit 0; fi
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
  echo "setup: installing libosmesa6 for headless MuJoCo rendering"
  (apt-get install -y -q libosmesa6 libgl1 >/dev/null 2>&1 || \
   (apt-get update -q >/dev/null 2>&1 && apt-get install -y -q libosmesa6 libgl1 >/dev/null 2>&1)) \
   || echo "setup: WARNING could not install libosmesa6; DMC pixel tasks will not render"
else
  echo "setup: WARNING libOSMesa not found; install libosmesa6 (Debian/Ubuntu) to render DMC tasks headless"
fi
