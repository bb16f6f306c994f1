#!/usr/bin/env bash
# Build the user guide (docs/ -> docs/_build/html): set-up as the quick start, the docs extra, then Sphinx with
# warnings as errors; the gallery's examples (docs/examples/plot_*.py) run during the build at small scale.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
bash scripts/bootstrap.sh
stamp=".venv/.docs-$(sha1sum pyproject.toml | cut -c1-12)"
if [ ! -f "$stamp" ]; then
    echo "[docs] installing the docs extra (Sphinx, sphinx-gallery) into .venv"
    .venv/bin/python -m pip install -q -e ".[docs]"
    rm -f .venv/.docs-* && touch "$stamp"
fi
.venv/bin/python -m sphinx -W --keep-going -q -b html docs docs/_build/html
echo "[docs] built docs/_build/html/index.html"
