#!/usr/bin/env bash
# Download TUM RGB-D sequences (CC BY 4.0) into TARGET.
#   usage: data/download_tum.sh TARGET [SEQUENCE ...]
#   e.g.   data/download_tum.sh ~/datasets/tum rgbd_dataset_freiburg3_teddy rgbd_dataset_freiburg1_desk
# Default sequence: rgbd_dataset_freiburg3_teddy. Each ends up as TARGET/<sequence>/ with rgb.txt,
# depth.txt and groundtruth.txt, ready for `gsslam run TARGET/<sequence> --dataset tum`.
set -euo pipefail

if [[ $# -lt 1 ]]; then
    echo "usage: $0 TARGET [SEQUENCE ...]   (default: rgbd_dataset_freiburg3_teddy)" >&2
    exit 2
fi
target=$1
shift
sequences=("$@")
[[ ${#sequences[@]} -eq 0 ]] && sequences=(rgbd_dataset_freiburg3_teddy)
base=${TUM_BASE_URL:-https://cvg.cit.tum.de/rgbd/dataset}

mkdir -p "$target"
for seq in "${sequences[@]}"; do
    if [[ ! $seq =~ ^rgbd_dataset_freiburg([123])_ ]]; then
        echo "error: '$seq' is not a TUM sequence name like rgbd_dataset_freiburg3_teddy" >&2
        exit 2
    fi
    sensor=${BASH_REMATCH[1]}
    if [[ -f $target/$seq/rgb.txt ]]; then
        echo "$seq: already in $target, skipping"
        continue
    fi
    url="$base/freiburg$sensor/$seq.tgz"
    echo "downloading $url"
    curl -fL --retry 3 -o "$target/$seq.tgz.part" "$url"
    mv "$target/$seq.tgz.part" "$target/$seq.tgz"
    tar -xzf "$target/$seq.tgz" -C "$target"
    rm "$target/$seq.tgz"
done
echo "done: ${sequences[*]} in $target"
