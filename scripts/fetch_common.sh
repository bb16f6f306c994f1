# Shared by the fetch_*.sh scripts (sourced, not run): one checked download step.
# The caller defines fail() (prints its own name and the message to stderr, exits 1).

# fetch_file REPO_PATH URL OUT TAG: download URL to OUT through OUT.part; any failure (curl error, HTTP error under
# -f, an empty file) removes the part file and stops the script naming REPO_PATH. Every step is tested explicitly:
# `a && b` does not stop a `set -e` script when `a` fails, and a failed fetch must never be reported as fetched.
fetch_file() {
    local f="$1" url="$2" out="$3" tag="$4"
    mkdir -p "$(dirname "$out")"
    if ! curl -fsSL --retry 3 -o "$out.part" "$url"; then
        rm -f "$out.part"
        fail "could not fetch $f from $url (curl failed, see above); $out not written"
    fi
    # none of these files is empty: an empty one is a broken mirror, not data
    if [ ! -s "$out.part" ]; then
        rm -f "$out.part"
        fail "could not fetch $f from $url: it is empty; $out not written"
    fi
    mv "$out.part" "$out"
    echo "[$tag] $f"
}
