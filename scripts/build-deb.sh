#!/bin/bash
# Builds ./mbgw.deb (or the path given) with Debian's tools: dpkg-buildpackage, debhelper,
# pybuild, which also run the unit tests against Debian's python3, click and cffi.  The build
# happens in a temporary copy of the checkout (its tracked and untracked files, not what
# .gitignore leaves out: .venv, built .so), so the checkout stays clean.
# Needs the Build-Depends: scripts/setup.sh installs them (apt-get build-dep ./).
set -euo pipefail
cd "$(dirname "$0")/.."
out=$(realpath -m "${1:-mbgw.deb}")
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
chmod 755 "$work"        # tests run as another user (nobody) must reach the build tree

mkdir "$work/src"
git ls-files -z -co --exclude-standard | while IFS= read -r -d '' file; do
    [ -e "$file" ] && cp --parents -P -- "$file" "$work/src/"     # skip files deleted here
done

# Debian's own python3 and nothing else: pyenv's shims or an active venv would be found first
# by pybuild ("No module named build", debian-packaging.md pitfall P1).
(cd "$work/src" && env -i HOME="$work" PATH=/usr/sbin:/usr/bin:/sbin:/bin LANG=C.UTF-8 \
    DEB_BUILD_OPTIONS="noddebs ${DEB_BUILD_OPTIONS:-}" dpkg-buildpackage -us -uc -b -J"$(nproc)")

debs=("$work"/mbgw_*.deb)
[ ${#debs[@]} -eq 1 ] && [ -f "${debs[0]}" ] || { echo "build-deb: no single mbgw_*.deb" >&2; exit 1; }
cp "${debs[0]}" "$out"
echo "build-deb: $out ($(dpkg-deb -f "$out" Package Version Architecture | tr '\n' ' '))"
