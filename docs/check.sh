#!/usr/bin/env bash
# Build the documentation with warnings as errors (the gallery's examples run), then
# open pages of the built site in headless Chromium and fail on any console error.
# Usage: bash docs/check.sh [OUTDIR]   (default docs/_build/html)
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-docs/_build/html}"
python3 -m sphinx -W --keep-going -q -b html docs "$out"
python3 docs/check_site.py "$out" index.html user_guide/index.html \
    user_guide/grid_method.html auto_examples/index.html auto_examples/00_plate_with_hole.html \
    auto_examples/02_vibrated_stack.html auto_examples/08_high_speed_sequence.html \
    auto_examples/09_tensile_coupon.html user_guide/sequences.html user_guide/gauges.html \
    user_guide/warnings_errors.html api/index.html api/series.html api/post.html api/identify.html \
    user_guide/identification.html user_guide/stress_gauge.html \
    benchmarks.html
