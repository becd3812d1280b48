#!/usr/bin/env bash
# Install the PDAL command line (Debian bullseye's pdal 2.2.0) into a private prefix, without
# touching the system's packages. Debian bookworm and trixie ship no PDAL; bullseye's builds
# run on bookworm when bookworm's own C runtime is used (see ../shared/INFRA.md).
#
# Usage: bash scripts/install_pdal.sh [PREFIX]      (default: $PDAL_PREFIX or /opt/canopyblocks-pdal)
# Prints the path of the wrapper PREFIX/bin/pdal on stdout at the end. Idempotent: does nothing
# when PREFIX/bin/pdal --version already works. Needs apt-get, dpkg-deb and the Debian archive
# keyring (package debian-archive-keyring); about 62 MB download, 200 MB on disk, ~15 s.
#
# How: a private apt configuration that lists only bullseye (+ -security, -updates), with its own
# lists/cache folders and an EMPTY dpkg status file, resolves the full dependency closure of
# `pdal libpdal-plugins` (`apt-get -s install`, reading the Inst lines); the host's base and C
# runtime packages are dropped (bookworm's are newer and compatible; bullseye's libc must never
# load); the rest is downloaded with `apt-get download` and unpacked with `dpkg-deb -x`.
# The wrapper sets LD_LIBRARY_PATH, GDAL_DATA, PROJ_LIB and PDAL_DRIVER_PATH for pdal only:
# never export that environment into Python or QGIS (it breaks their GDAL/PROJ/Qt).
set -euo pipefail

PREFIX="${1:-${PDAL_PREFIX:-/opt/canopyblocks-pdal}}"
WRAPPER="$PREFIX/bin/pdal"
say() { echo "install_pdal: $*" >&2; }

if [ -x "$WRAPPER" ] && "$WRAPPER" --version >/dev/null 2>&1; then
    say "already installed: $("$WRAPPER" --version 2>/dev/null | grep -o 'pdal [0-9.]*' | head -1)"
    echo "$WRAPPER"
    exit 0
fi

for tool in apt-get dpkg-deb dpkg; do
    command -v "$tool" >/dev/null || { say "needs $tool (a Debian-based system)"; exit 2; }
done
ARCH="$(dpkg --print-architecture)"
case "$ARCH" in
    amd64) TRIPLET=x86_64-linux-gnu ;;
    arm64) TRIPLET=aarch64-linux-gnu ;;
    *) say "unsupported architecture $ARCH (amd64 or arm64)"; exit 2 ;;
esac

WORK="$(mktemp -d "${TMPDIR:-/tmp}/canopyblocks-pdal.XXXXXX")"
trap 'rm -rf "$WORK"' EXIT
mkdir -p "$WORK/lists/partial" "$WORK/cache/archives/partial" "$WORK/debs"
: >"$WORK/status"

# The keys that sign bullseye: bookworm's debian-archive-keyring ships them in the combined
# keyring and as debian-archive-bullseye-*.gpg (later releases may keep only the latter).
# Binary keyrings concatenate, so apt gets one file holding every one found here.
: >"$WORK/keyring.gpg"
for k in /usr/share/keyrings/debian-archive-keyring.gpg \
         /usr/share/keyrings/debian-archive-bullseye-stable.gpg \
         /usr/share/keyrings/debian-archive-bullseye-automatic.gpg \
         /usr/share/keyrings/debian-archive-bullseye-security-automatic.gpg; do
    if [ -r "$k" ]; then cat "$k" >>"$WORK/keyring.gpg"; fi
done
if [ ! -s "$WORK/keyring.gpg" ]; then
    say "no Debian archive keyring in /usr/share/keyrings; run: apt-get install debian-archive-keyring"
    exit 2
fi
KEYRING="$WORK/keyring.gpg"

APT_OPTS=(
    -o "Dir::Etc::SourceList=$WORK/sources.list"
    -o "Dir::Etc::SourceParts=/dev/null"
    -o "Dir::Etc::Preferences=/dev/null"
    -o "Dir::Etc::PreferencesParts=/dev/null"
    -o "Dir::State::Lists=$WORK/lists"
    -o "Dir::State::status=$WORK/status"
    -o "Dir::Cache=$WORK/cache"
    -o "APT::Architecture=$ARCH"
    -o "APT::Architectures::=$ARCH"
    -o "APT::Get::Assume-Yes=true"
    -o "Acquire::Check-Valid-Until=false"
    -o "Debug::NoLocking=true"
)

# Resolve the closure from one mirror (a base URL such as http://deb.debian.org).
resolve() {
    printf 'deb [signed-by=%s] %s/debian bullseye main\n' "$KEYRING" "$1" >"$WORK/sources.list"
    printf 'deb [signed-by=%s] %s/debian bullseye-updates main\n' "$KEYRING" "$1" \
        >>"$WORK/sources.list"
    printf 'deb [signed-by=%s] %s/debian-security bullseye-security main\n' "$KEYRING" "$1" \
        >>"$WORK/sources.list"
    rm -rf "${WORK:?}/lists" && mkdir -p "$WORK/lists/partial"
    apt-get "${APT_OPTS[@]}" -qq update >"$WORK/update.log" 2>&1 &&
        apt-get "${APT_OPTS[@]}" -s --no-install-recommends install pdal libpdal-plugins \
            >"$WORK/sim.log" 2>&1
}

# bullseye is on deb.debian.org until it is archived, then on archive.debian.org;
# PDAL_DEBIAN_MIRROR replaces both (e.g. a local mirror).
say "reading the Debian bullseye package lists"
ok=""
for mirror in ${PDAL_DEBIAN_MIRROR:-http://deb.debian.org http://archive.debian.org}; do
    if resolve "$mirror"; then ok=1; break; fi
    say "bullseye's pdal is not available from $mirror"
done
if [ -z "$ok" ]; then
    cat "$WORK/update.log" "$WORK/sim.log" >&2 2>/dev/null || true
    say "could not resolve pdal from Debian bullseye (network, keyring or mirror)"
    exit 1
fi
# "Inst NAME (VERSION ...)" lines: the closure against an empty system.
awk '$1 == "Inst" { print $2 }' "$WORK/sim.log" | sed 's/:.*$//' | sort -u >"$WORK/all.txt"

# The host keeps its own (newer, compatible) C runtime and base system.
SKIP='^(libc6|libc-bin|libc-l10n|locales|libgcc-s1|libstdc\+\+6|gcc-10-base|gcc-[0-9]+-base|libcrypt1|zlib1g|liblzma5|libzstd1|libbz2-1\.0|dpkg|tar|coreutils|perl-base|debconf|debianutils|base-files|base-passwd|bash|dash|diffutils|findutils|grep|gzip|hostname|init-system-helpers|login|mawk|ncurses-base|ncurses-bin|sed|sensible-utils|sysvinit-utils|util-linux|libselinux1|libpcre2-8-0|libpcre3|libacl1|libattr1|libaudit1|libaudit-common|libcap-ng0|libpam0g|libpam-modules|libpam-modules-bin|libpam-runtime|libdebconfclient0|libtinfo6|libmd0|libsystemd0|libudev1|lsb-base|libgpg-error0|libgcrypt20|liblz4-1|libuuid1|libblkid1|libmount1|libsmartcols1|libdb5\.3|libsemanage1|libsemanage-common|libsepol1|libzstd1|adduser|passwd|readline-common|libreadline8|mount|debian-archive-keyring)$'
# ... but only those the host really has; anything else comes from bullseye.
: >"$WORK/get.txt"
while read -r pkg; do
    if [[ "$pkg" =~ $SKIP ]] && dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q 'ok installed'; then
        continue
    fi
    echo "$pkg" >>"$WORK/get.txt"
done <"$WORK/all.txt"
n_get="$(wc -l <"$WORK/get.txt")"
say "downloading $n_get packages (of $(wc -l <"$WORK/all.txt") in the closure)"
(cd "$WORK/debs" && xargs -a "$WORK/get.txt" apt-get "${APT_OPTS[@]}" -qq download) \
    >"$WORK/download.log" 2>&1 || { cat "$WORK/download.log" >&2; say "download failed"; exit 1; }

# Unpack into a fresh folder beside PREFIX, then move it into place (no half-installed prefix).
STAGE="$PREFIX.part.$$"
rm -rf "$STAGE"
mkdir -p "$STAGE/bin"
for deb in "$WORK"/debs/*.deb; do
    dpkg-deb -x "$deb" "$STAGE"
done
[ -x "$STAGE/usr/bin/pdal" ] || { say "pdal binary missing after unpacking"; rm -rf "$STAGE"; exit 1; }

PROJ_DIR=usr/share/proj
GDAL_DIR=usr/share/gdal
cat >"$STAGE/bin/pdal" <<EOF
#!/bin/sh
# PDAL (Debian bullseye build) installed by canopyblocks' scripts/install_pdal.sh.
# The environment below is for this process only: never export it into Python or QGIS.
P="\$(cd "\$(dirname "\$(readlink -f "\$0")")/.." && pwd)"
L="\$P/usr/lib/$TRIPLET"
LD_LIBRARY_PATH="\$P/usr/lib:\$L:\$L/blas:\$L/lapack:\$P/lib/$TRIPLET\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}"
GDAL_DATA="\$P/$GDAL_DIR"
PROJ_LIB="\$P/$PROJ_DIR"
PDAL_DRIVER_PATH="\$P/usr/lib:\$L"
export LD_LIBRARY_PATH GDAL_DATA PROJ_LIB PDAL_DRIVER_PATH
unset PROJ_DATA GDAL_DRIVER_PATH
exec "\$P/usr/bin/pdal" "\$@"
EOF
chmod 755 "$STAGE/bin/pdal"

if ! "$STAGE/bin/pdal" --version >"$WORK/version.log" 2>&1; then
    cat "$WORK/version.log" >&2
    say "the unpacked pdal does not run; left in $STAGE for inspection"
    trap - EXIT; rm -rf "$WORK"
    exit 1
fi
rm -rf "$PREFIX"
mkdir -p "$(dirname "$PREFIX")"
mv "$STAGE" "$PREFIX"
say "installed $(grep -o 'pdal [0-9.]*' "$WORK/version.log" | head -1) in $PREFIX"
echo "$WRAPPER"
