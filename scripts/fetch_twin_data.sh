#!/usr/bin/env bash
# Put the real static image pairs that benchmarks/twin_real.py validates the digital twin on into a test-data
# folder (default data/twin, git-ignored). All come from DICe's regression tests (https://github.com/dicengine/dice,
# BSD 3-Clause licence, NTESS / Sandia National Laboratories):
#
#   gt4/        tests/regression/stereo_d_spec: the GT4 specimen of Stereo-DIC Challenge 1.0 Sample 3, two cameras,
#               1920 x 1200 8-bit, frames 0 and 1 (near static: the loading ramp starts there), VIC-3D calibration
#   staticb/    tests/regression/stereo_list: "StaticB", six exposures of an unmoved speckled coupon, two cameras,
#               1280 x 800 8-bit (the cal.xml shipped with it does not fit these images: 11.5 px triangulation
#               residual even with DICe's own matches, so the set serves as two one-camera static sets)
#   sample5/    tests/regression/dic_challenge_5_znssd: DIC Challenge 1.0 Sample 5 (synthetic, 512 x 512), the
#               reference and the zero-shift frame "X0.00 Y0.00 N2 C75 R10" (another noise draw and contrast)
#   mechanism/  tests/regression/simple_tracking: a real 640 x 480 camera sequence whose wood-panel background is static
#
#   scripts/fetch_twin_data.sh [--mirror GIT_DIR | --base-url URL] [--commit REV] [--dest DIR] [--list]
#
#   --mirror GIT_DIR  a local (bare) git copy of DICe: files are taken with `git show REV:path` (offline)
#   --base-url URL    where the repository's files are instead of raw.githubusercontent.com/dicengine/dice/REV:
#                     a file:// URL or a plain folder path (offline: a DICe checkout, or a folder holding the files
#                     at their repository paths, see --list) or another http(s) mirror; default
#                     $TWIN_DATA_BASE_URL when set. --commit does not apply (the folder is one commit's files)
#   --commit REV      commit or ref to take (default HEAD for a mirror, 5ebcdfaf... for a download)
#   --dest DIR        destination folder (default data/twin under the repository root)
#   --list            print the repository paths fetched, one a line, and exit (what a --base-url folder holds)
#
# Without --mirror the files are fetched with curl (-f: an HTTP error is a failure) from --base-url or from
# raw.githubusercontent.com (then it needs a network). Any file that cannot be fetched (download or HTTP error,
# missing in the mirror, empty) stops the script with the file named on stderr and exit status 1; the files
# fetched before it are kept, SOURCE.txt is not written.
# The folder gets SOURCE.txt (where the files came from, the commit, the licence) and LICENSE.txt (DICe's).
# Idempotent: files already present (with the right size, for a git mirror) are kept.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
mirror=""
base_url="${TWIN_DATA_BASE_URL:-}"
rev=""
dest="$here/data/twin"
list=0
fail() { echo "fetch_twin_data: $*" >&2; exit 1; }
# shellcheck source=fetch_common.sh
. "$here/scripts/fetch_common.sh"
while [ $# -gt 0 ]; do
    case "$1" in
        --mirror) mirror="$2"; shift 2 ;;
        --base-url) base_url="$2"; shift 2 ;;
        --commit) rev="$2"; shift 2 ;;
        --dest) dest="$2"; shift 2 ;;
        --list) list=1; shift ;;
        # the header comment, up to the first line of code, is the help
        -h|--help) awk 'NR > 1 && !/^#/ {exit} NR > 1 {sub(/^# ?/, ""); print}' "$0"; exit 0 ;;
        *) echo "fetch_twin_data: unknown argument $1 (see --help)" >&2; exit 2 ;;
    esac
done
if [ -n "$mirror" ] && [ -n "$base_url" ]; then
    echo "fetch_twin_data: --mirror and --base-url (or \$TWIN_DATA_BASE_URL) both given: choose one" >&2; exit 2
fi

# "repository path|destination path"
pairs=("LICENSE|LICENSE.txt"
       "tests/regression/stereo_d_spec/cal.xml|gt4/cal.xml")
for f in 0000_0 0000_1 0001_0 0001_1; do pairs+=("tests/regression/stereo_d_spec/images/GT4-$f.tif|gt4/GT4-$f.tif"); done
for k in 0 1 2 3 4 5; do
    for c in 0 1; do pairs+=("tests/regression/stereo_list/images/img_000${k}_$c.tif|staticb/img_000${k}_$c.tif"); done
done
pairs+=("tests/regression/dic_challenge_5_znssd/images/Sample5 Reference.tif|sample5/Sample5 Reference.tif"
        "tests/regression/dic_challenge_5_znssd/images/Sample5-000 X0.00 Y0.00 N2 C75 R10.tif|sample5/Sample5-000 X0.00 Y0.00 N2 C75 R10.tif")
for k in 4870 4871 4872 4880; do
    pairs+=("tests/regression/simple_tracking/images/mechanism_$k.tif|mechanism/mechanism_$k.tif")
done

if [ "$list" = 1 ]; then
    for pair in "${pairs[@]}"; do printf '%s\n' "${pair%%|*}"; done
    exit 0
fi

# Each step is tested explicitly: `a && b` does not stop a `set -e` script when `a` fails, and a failed fetch
# must never be reported as fetched.
mkdir -p "$dest"
if [ -n "$mirror" ]; then
    rev="${rev:-HEAD}"
    git=(git --git-dir="$mirror")
    commit="$("${git[@]}" rev-parse --verify --quiet "$rev^{commit}")" \
        || fail "--mirror $mirror: no commit $rev there (is it a git directory of DICe?)"
    for pair in "${pairs[@]}"; do
        f="${pair%%|*}"; out="$dest/${pair##*|}"
        size="$("${git[@]}" cat-file -s "$commit:$f" 2>/dev/null)" \
            || fail "could not fetch $f: not in the git mirror $mirror at commit $commit"
        if [ -f "$out" ] && [ "$(stat -c %s "$out")" = "$size" ]; then continue; fi
        mkdir -p "$(dirname "$out")"
        if ! "${git[@]}" show "$commit:$f" > "$out.part"; then
            rm -f "$out.part"
            fail "could not fetch $f from the git mirror $mirror (git show failed)"
        fi
        mv "$out.part" "$out"
        echo "[fetch_twin_data] $f"
    done
    source_line="git mirror $mirror, commit $commit"
else
    command -v curl >/dev/null || fail "curl not found (or use --mirror)"
    if [ -n "$base_url" ]; then
        # a plain folder path becomes a file:// URL, so one code path (curl -f) serves both
        case "$base_url" in
            *://*) base="${base_url%/}" ;;
            *) [ -d "$base_url" ] || fail "--base-url $base_url: no such folder (nor a URL)"
               base="file://$(cd "$base_url" && pwd)" ;;
        esac
        source_line="mirror $base (copied $(date -u +%Y-%m-%dT%H:%MZ))"
    else
        rev="${rev:-5ebcdfaf}"
        base="https://raw.githubusercontent.com/dicengine/dice/$rev"
        source_line="https://github.com/dicengine/dice at $rev (downloaded $(date -u +%Y-%m-%dT%H:%MZ))"
    fi
    for pair in "${pairs[@]}"; do
        f="${pair%%|*}"; out="$dest/${pair##*|}"
        [ -s "$out" ] && continue
        fetch_file "$f" "$base/$(printf '%s' "$f" | sed 's/ /%20/g')" "$out" fetch_twin_data
    done
fi
cat > "$dest/SOURCE.txt" <<EOF
Real static image pairs from DICe's regression tests (https://github.com/dicengine/dice, tests/regression/).
Licence: BSD 3-Clause (LICENSE.txt here, copied from the repository), NTESS / Sandia National Laboratories.
Source: $source_line
Fetched by scripts/fetch_twin_data.sh
EOF
echo "[fetch_twin_data] ${#pairs[@]} files in $dest ($source_line)"
