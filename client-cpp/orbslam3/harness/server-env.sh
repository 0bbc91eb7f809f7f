#!/usr/bin/env bash
# Prints the environment the ORB-SLAM3 harness (run.sh) gives `humem serve`
# for a camera of WIDTH x HEIGHT pixels, one KEY=VALUE per line, so that
# run.sh and a CI check (that `humem serve` accepts them) use the same:
#
#   client-cpp/orbslam3/harness/server-env.sh 512 288
#   HUMEM_PERCEPTION__OCR__DETECTOR_LONG_SIDE=512
#
# The OCR text detector reads the image scaled so that its long side is
# `perception.ocr.detector_long_side` pixels (then padded to multiples of
# 32): the camera's own long side, rounded down to a multiple of 32 (within
# the server's 32..4096), reads what the pixels hold at the least cost.
set -euo pipefail
if [ $# -ne 2 ] || ! [[ "$1" =~ ^[0-9]+$ ]] || ! [[ "$2" =~ ^[0-9]+$ ]] || [ "$1" -lt 1 ] || [ "$2" -lt 1 ]; then
    echo "usage: $0 WIDTH HEIGHT   (the camera's size in pixels)" >&2
    exit 2
fi
width=$1 height=$2
long=$(( width > height ? width : height ))
long=$(( long / 32 * 32 ))
(( long < 32 )) && long=32
(( long > 4096 )) && long=4096
echo "HUMEM_PERCEPTION__OCR__DETECTOR_LONG_SIDE=$long"
