#!/usr/bin/env bash
# Put the MultiDIC sample data that benchmarks/real_multidic.py and tests/test_real_multidic.py need into a
# test-data folder (default data/multidic, git-ignored).
#
# MultiDIC (https://github.com/MultiDIC/MultiDIC, Apache License 2.0, Dana Solav et al.) ships a stereo sample:
# a speckled cylinder (nominal radius 57.0 mm, that of the calibration object's targets) seen by cameras 201 and
# 202, each camera's checkerboard images, and the images and 2-D/3-D target coordinates of a calibration object.
#
#   scripts/fetch_multidic.sh [--mirror GIT_DIR] [--commit REV] [--dest DIR]
#
#   --mirror GIT_DIR  a local (bare) git copy of MultiDIC: files are taken with `git show REV:path` (offline)
#   --commit REV      commit or ref to take (default HEAD for a mirror, master for a download)
#   --dest DIR        destination folder (default data/multidic under the repository root)
#
# Without --mirror the files are downloaded from raw.githubusercontent.com (needs curl and a network).
# The folder gets SOURCE.txt (where the files came from, the commit, the licence) and LICENSE.txt (MultiDIC's).
# Idempotent: files already present with the right size are kept.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
mirror=""
rev=""
dest="$here/data/multidic"
while [ $# -gt 0 ]; do
    case "$1" in
        --mirror) mirror="$2"; shift 2 ;;
        --commit) rev="$2"; shift 2 ;;
        --dest) dest="$2"; shift 2 ;;
        -h|--help) sed -n '2,17p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) echo "fetch_multidic: unknown argument $1 (see --help)" >&2; exit 2 ;;
    esac
done

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

mkdir -p "$dest"
if [ -n "$mirror" ]; then
    rev="${rev:-HEAD}"
    git=(git --git-dir="$mirror")
    commit="$("${git[@]}" rev-parse "$rev^{commit}")"
    # With a mirror, take the checkerboard lists from the tree itself.
    mapfile -t cbs < <("${git[@]}" ls-tree -r --name-only "$commit" -- sample_data/BAcheckerboardImages/201 \
                        sample_data/BAcheckerboardImages/202 | grep -i '\.jpg$')
    files+=("${cbs[@]}")
    for f in "${files[@]}"; do
        out="$dest/${f#sample_data/}"
        size="$("${git[@]}" cat-file -s "$commit:$f")"
        if [ -f "$out" ] && [ "$(stat -c %s "$out")" = "$size" ]; then continue; fi
        mkdir -p "$(dirname "$out")"
        "${git[@]}" show "$commit:$f" > "$out.part" && mv "$out.part" "$out"
        echo "[fetch_multidic] $f"
    done
    source_line="git mirror $mirror, commit $commit"
else
    rev="${rev:-master}"
    command -v curl >/dev/null || { echo "fetch_multidic: curl not found (or use --mirror)" >&2; exit 1; }
    for k in "${cb201[@]}"; do files+=("sample_data/BAcheckerboardImages/201/201_$k.jpg"); done
    for k in "${cb202[@]}"; do files+=("sample_data/BAcheckerboardImages/202/202_$k.jpg"); done
    base="https://raw.githubusercontent.com/MultiDIC/MultiDIC/$rev"
    for f in "${files[@]}"; do
        out="$dest/${f#sample_data/}"
        [ -s "$out" ] && continue
        mkdir -p "$(dirname "$out")"
        url="$base/$(printf '%s' "$f" | sed 's/ /%20/g')"
        curl -fsSL --retry 3 -o "$out.part" "$url" && mv "$out.part" "$out"
        echo "[fetch_multidic] $f"
    done
    commit="$rev (downloaded $(date -u +%Y-%m-%dT%H:%MZ))"
    source_line="https://github.com/MultiDIC/MultiDIC at $commit"
fi
cat > "$dest/SOURCE.txt" <<EOF
MultiDIC sample data (https://github.com/MultiDIC/MultiDIC, sample_data/), by Dana Solav et al.
Licence: Apache License 2.0 (LICENSE.txt here, copied from the repository).
Source: $source_line
Fetched by scripts/fetch_multidic.sh
EOF
echo "[fetch_multidic] ${#files[@]} files in $dest ($source_line)"
