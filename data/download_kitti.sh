#!/usr/bin/env bash
# Prepare the KITTI odometry benchmark (CC BY-NC-SA 3.0: non-commercial use only) in TARGET.
#   usage: data/download_kitti.sh TARGET [ZIP_DIR]
#
# KITTI requires registration: create an account at https://www.cvlibs.net/datasets/kitti/eval_odometry.php
# and download there (the page e-mails / shows the links after you accept the terms)
#     data_odometry_gray.zip    (grayscale images, ~22 GB)
#     data_odometry_calib.zip   (calib.txt, times.txt)
#     data_odometry_poses.zip   (ground truth poses of sequences 00-10)
# into ZIP_DIR (default: TARGET). This script then unpacks them into TARGET/dataset/
# (sequences/XX/{image_0,image_1,calib.txt,times.txt}, poses/XX.txt), ready for
# `gsslam run TARGET/dataset/sequences/06 --dataset kitti`.
# If you have a download link from the KITTI page, set KITTI_BASE_URL to its folder and the script
# fetches the missing zips itself.
set -euo pipefail

if [[ $# -lt 1 ]]; then
    echo "usage: $0 TARGET [ZIP_DIR]" >&2
    exit 2
fi
target=$1
zips=${2:-$target}
mkdir -p "$target" "$zips"

for name in data_odometry_calib data_odometry_poses data_odometry_gray; do
    zip="$zips/$name.zip"
    if [[ ! -f $zip ]]; then
        if [[ -n ${KITTI_BASE_URL:-} ]]; then
            echo "downloading $KITTI_BASE_URL/$name.zip"
            curl -fL --retry 3 -o "$zip.part" "$KITTI_BASE_URL/$name.zip"
            mv "$zip.part" "$zip"
        else
            echo "error: $zip is missing. KITTI needs registration: sign up at" >&2
            echo "  https://www.cvlibs.net/datasets/kitti/eval_odometry.php, download $name.zip into $zips" >&2
            echo "  (or set KITTI_BASE_URL to the download folder you were given) and run this again." >&2
            exit 1
        fi
    fi
    echo "unpacking $zip"
    unzip -q -n "$zip" -d "$target"
done
echo "done: KITTI odometry in $target/dataset"
