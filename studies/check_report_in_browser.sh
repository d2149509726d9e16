#!/usr/bin/env bash
# Render a study report in headless Chromium and write a full-page PNG screenshot.
#
#   studies/check_report_in_browser.sh DIR [SCREENSHOT.png [HEIGHT]]
#
# DIR is a folder written by `prp3mc study ... --out DIR`; the screenshot goes
# to DIR/report_screenshot.png unless given; the window is 1400 x HEIGHT
# pixels (default 6000; the paper_reproduction report needs ~12000 to show
# to its end). Look at it: every figure of the
# report must show (they are embedded in report.html as data: URIs, so a
# missing figure is a broken report, not a missing file). Exit status 1 if
# Chromium fails or writes no screenshot.
# Needs Chromium: apt-get update && apt-get install -y chromium
set -euo pipefail
dir=${1:?usage: $0 DIR [SCREENSHOT.png [HEIGHT]]}
report=$(cd "$dir" && pwd)/report.html
shot=${2:-$dir/report_screenshot.png}
height=${3:-6000}
[[ -f $report ]] || { echo "$0: no report.html in $dir" >&2; exit 1; }
browser=${CHROMIUM:-/usr/bin/chromium}
profile=$(mktemp -d)
trap 'rm -rf "$profile"' EXIT
"$browser" --headless --no-sandbox --disable-gpu --disable-quic --no-first-run \
  --disable-background-networking --disable-component-update --disable-sync \
  --user-data-dir="$profile" --hide-scrollbars --screenshot="$shot" --window-size=1400,"$height" \
  "file://$report" >/dev/null 2>&1
[[ -s $shot ]] || { echo "$0: Chromium wrote no screenshot" >&2; exit 1; }
echo "$shot"
