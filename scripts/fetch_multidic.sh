#!/usr/bin/env bash
# Put the MultiDIC sample data that benchmarks/real_multidic.py and tests/test_real_multidic.py need into a
# test-data folder (default data/multidic, git-ignored).
#
# MultiDIC (https://github.com/MultiDIC/MultiDIC, Apache License 2.0, Dana Solav et al.) ships a stereo sample:
# a speckled cylinder (nominal radius 57.0 mm, that of the calibration object's targets) seen by cameras 201 and
# 202, each camera's checkerboard images, and the images and 2-D/3-D target coordinates of a calibration object.
#
#   scripts/fetch_multidic.sh [--mirror GIT_DIR | --base-url URL] [--commit REV] [--dest DIR] [--list]
#
#   --mirror GIT_DIR  a local (bare) git copy of MultiDIC: files are taken with `git show REV:path` (offline)
#   --base-url URL    where the repository's files are instead of raw.githubusercontent.com/MultiDIC/MultiDIC/REV:
#                     a file:// URL or a plain folder path (offline: a MultiDIC checkout, or a folder holding the
#                     files at their repository paths, see --list) or another http(s) mirror; default
#                     $MULTIDIC_BASE_URL when set. --commit does not apply (the folder is one commit's files)
#   --commit REV      commit or ref to take (default HEAD for a mirror, master for a download)
#   --dest DIR        destination folder (default data/multidic under the repository root)
#   --list            print the repository paths fetched without --mirror, one a line, and exit
#
# Without --mirror the files are fetched with curl (-f: an HTTP error is a failure) from --base-url or from
# raw.githubusercontent.com (then it needs a network). Any file that cannot be fetched (download or HTTP error,
# missing in the mirror, empty) stops the script with the file named on stderr and exit status 1; the files
# fetched before it are kept, SOURCE.txt is not written.
# The folder gets SOURCE.txt (where the files came from, the commit, the licence) and LICENSE.txt (MultiDIC's).
# Idempotent: files already present (with the right size, for a git mirror) are kept.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
mirror=""
base_url="${MULTIDIC_BASE_URL:-}"
rev=""
dest="$here/data/multidic"
list=0
fail() { echo "fetch_multidic: $*" >&2; exit 1; }
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
        *) echo "fetch_multidic: unknown argument $1 (see --help)" >&2; exit 2 ;;
    esac
done
if [ -n "$mirror" ] && [ -n "$base_url" ]; then
    echo "fetch_multidic: --mirror and --base-url (or \$MULTIDIC_BASE_URL) both given: choose one" >&2; exit 2
fi

# The files needed, relative to the repository root (checkerboard lists: every image of both cameras).
files=(
    LICENSE.txt
    "sample_data/Sample data instructions.pdf"
    sample_data/BAcheckerboardImages/cameraCBparameters_cam_201.mat
    sample_data/BAcheckerboardImages/cameraCBparameters_cam_202.mat
    sample_data/BAcheckerboardImages/figures/params_cam201.fig
    sample_data/BAcheckerboardImages/figures/params_cam202.fig
    sample_data/calibrationObjectImages/201.jpg
    sample_data/calibrationObjectImages/202.jpg
    sample_data/calibrationObjectImages/DLTstruct_cam_201.mat
    sample_data/calibrationObjectImages/DLTstruct_cam_202.mat
    sample_data/calibrationObjectImages/calibrationObjectCoordinates.mat
    sample_data/speckledObjectImages/ROIMask_C_201_C_202.mat
)
for cam in 201 202; do
    for k in 1 2 3 4 5; do files+=("sample_data/speckledObjectImages/$cam/${cam}_$k.jpg"); done
done
cb201=(02 03 04 05 06 07 08 12 13 18 19 20 22 23 24 25 35 36 37 38 39 40 41 43 44)
cb202=(01 02 03 04 05 06 07 08 09 10 11 12 13 14 15 16 17 18 19 20 21 22 23 24 25)

if [ "$list" = 1 ]; then
    for k in "${cb201[@]}"; do files+=("sample_data/BAcheckerboardImages/201/201_$k.jpg"); done
    for k in "${cb202[@]}"; do files+=("sample_data/BAcheckerboardImages/202/202_$k.jpg"); done
    printf '%s\n' "${files[@]}"
    exit 0
fi

# Each step is tested explicitly: `a && b` does not stop a `set -e` script when `a` fails, and a failed fetch
# must never be reported as fetched.
mkdir -p "$dest"
if [ -n "$mirror" ]; then
    rev="${rev:-HEAD}"
    git=(git --git-dir="$mirror")
    commit="$("${git[@]}" rev-parse --verify --quiet "$rev^{commit}")" \
        || fail "--mirror $mirror: no commit $rev there (is it a git directory of MultiDIC?)"
    # With a mirror, take the checkerboard lists from the tree itself.
    mapfile -t cbs < <("${git[@]}" ls-tree -r --name-only "$commit" -- sample_data/BAcheckerboardImages/201 \
                        sample_data/BAcheckerboardImages/202 | grep -i '\.jpg$')
    [ "${#cbs[@]}" -gt 0 ] || fail "--mirror $mirror: no checkerboard images under sample_data/BAcheckerboardImages/"
    files+=("${cbs[@]}")
    for f in "${files[@]}"; do
        out="$dest/${f#sample_data/}"
        size="$("${git[@]}" cat-file -s "$commit:$f" 2>/dev/null)" \
            || fail "could not fetch $f: not in the git mirror $mirror at commit $commit"
        if [ -f "$out" ] && [ "$(stat -c %s "$out")" = "$size" ]; then continue; fi
        mkdir -p "$(dirname "$out")"
        if ! "${git[@]}" show "$commit:$f" > "$out.part"; then
            rm -f "$out.part"
            fail "could not fetch $f from the git mirror $mirror (git show failed)"
        fi
        mv "$out.part" "$out"
        echo "[fetch_multidic] $f"
    done
    source_line="git mirror $mirror, commit $commit"
else
    command -v curl >/dev/null || fail "curl not found (or use --mirror)"
    for k in "${cb201[@]}"; do files+=("sample_data/BAcheckerboardImages/201/201_$k.jpg"); done
    for k in "${cb202[@]}"; do files+=("sample_data/BAcheckerboardImages/202/202_$k.jpg"); done
    if [ -n "$base_url" ]; then
        # a plain folder path becomes a file:// URL, so one code path (curl -f) serves both
        case "$base_url" in
            *://*) base="${base_url%/}" ;;
            *) [ -d "$base_url" ] || fail "--base-url $base_url: no such folder (nor a URL)"
               base="file://$(cd "$base_url" && pwd)" ;;
        esac
        source_line="mirror $base (copied $(date -u +%Y-%m-%dT%H:%MZ))"
    else
        rev="${rev:-master}"
        base="https://raw.githubusercontent.com/MultiDIC/MultiDIC/$rev"
        source_line="https://github.com/MultiDIC/MultiDIC at $rev (downloaded $(date -u +%Y-%m-%dT%H:%MZ))"
    fi
    for f in "${files[@]}"; do
        out="$dest/${f#sample_data/}"
        [ -s "$out" ] && continue
        fetch_file "$f" "$base/$(printf '%s' "$f" | sed 's/ /%20/g')" "$out" fetch_multidic
    done
fi
cat > "$dest/SOURCE.txt" <<EOF
MultiDIC sample data (https://github.com/MultiDIC/MultiDIC, sample_data/), by Dana Solav et al.
Licence: Apache License 2.0 (LICENSE.txt here, copied from the repository).
Source: $source_line
Fetched by scripts/fetch_multidic.sh
EOF
echo "[fetch_multidic] ${#files[@]} files in $dest ($source_line)"
