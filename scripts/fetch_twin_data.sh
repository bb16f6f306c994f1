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
#   scripts/fetch_twin_data.sh [--mirror GIT_DIR] [--commit REV] [--dest DIR]
#
#   --mirror GIT_DIR  a local (bare) git copy of DICe: files are taken with `git show REV:path` (offline)
#   --commit REV      commit or ref to take (default HEAD for a mirror, 5ebcdfaf... for a download)
#   --dest DIR        destination folder (default data/twin under the repository root)
#
# Without --mirror the files are downloaded from raw.githubusercontent.com (needs curl and a network).
# The folder gets SOURCE.txt (where the files came from, the commit, the licence) and LICENSE.txt (DICe's).
# Idempotent: files already present with the right size are kept.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
mirror=""
rev=""
dest="$here/data/twin"
while [ $# -gt 0 ]; do
    case "$1" in
        --mirror) mirror="$2"; shift 2 ;;
        --commit) rev="$2"; shift 2 ;;
        --dest) dest="$2"; shift 2 ;;
        -h|--help) sed -n '2,23p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) echo "fetch_twin_data: unknown argument $1 (see --help)" >&2; exit 2 ;;
    esac
done

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

mkdir -p "$dest"
if [ -n "$mirror" ]; then
    rev="${rev:-HEAD}"
    git=(git --git-dir="$mirror")
    commit="$("${git[@]}" rev-parse "$rev^{commit}")"
    for pair in "${pairs[@]}"; do
        f="${pair%%|*}"; out="$dest/${pair##*|}"
        size="$("${git[@]}" cat-file -s "$commit:$f")"
        if [ -f "$out" ] && [ "$(stat -c %s "$out")" = "$size" ]; then continue; fi
        mkdir -p "$(dirname "$out")"
        "${git[@]}" show "$commit:$f" > "$out.part" && mv "$out.part" "$out"
        echo "[fetch_twin_data] $f"
    done
    source_line="git mirror $mirror, commit $commit"
else
    rev="${rev:-5ebcdfaf}"
    command -v curl >/dev/null || { echo "fetch_twin_data: curl not found (or use --mirror)" >&2; exit 1; }
    base="https://raw.githubusercontent.com/dicengine/dice/$rev"
    for pair in "${pairs[@]}"; do
        f="${pair%%|*}"; out="$dest/${pair##*|}"
        [ -s "$out" ] && continue
        mkdir -p "$(dirname "$out")"
        url="$base/$(printf '%s' "$f" | sed 's/ /%20/g')"
        curl -fsSL --retry 3 -o "$out.part" "$url" && mv "$out.part" "$out"
        echo "[fetch_twin_data] $f"
    done
    source_line="https://github.com/dicengine/dice at $rev (downloaded $(date -u +%Y-%m-%dT%H:%MZ))"
fi
cat > "$dest/SOURCE.txt" <<EOF
Real static image pairs from DICe's regression tests (https://github.com/dicengine/dice, tests/regression/).
Licence: BSD 3-Clause (LICENSE.txt here, copied from the repository), NTESS / Sandia National Laboratories.
Source: $source_line
Fetched by scripts/fetch_twin_data.sh
EOF
echo "[fetch_twin_data] ${#pairs[@]} files in $dest ($source_line)"
