#!/usr/bin/env bash
# Download EuRoC MAV sequences (ASL/ETH Zurich, research use; cite Burri et al., IJRR 2016) into TARGET.
#   usage: data/download_euroc.sh TARGET [SEQUENCE ...]      (default: V1_01_easy)
#   sequences: MH_01_easy .. MH_05_difficult, V1_01_easy .. V1_03_difficult, V2_01_easy .. V2_03_difficult
# Each ends up as TARGET/<sequence>/mav0/ (ASL layout, ground truth in
# mav0/state_groundtruth_estimate0/data.csv), ready for `gsslam run TARGET/<sequence> --dataset euroc`.
# The historical server is used by default; ASL has moved the data to the ETH Research Collection
# (https://www.research-collection.ethz.ch/handle/20.500.11850/690084). If the default server does not
# answer, set EUROC_BASE_URL to a mirror with the same <room>/<sequence>/<sequence>.zip layout, or
# download the zip by hand and unpack it into TARGET/<sequence>/.
set -euo pipefail

if [[ $# -lt 1 ]]; then
    echo "usage: $0 TARGET [SEQUENCE ...]   (default: V1_01_easy)" >&2
    exit 2
fi
target=$1
shift
sequences=("$@")
[[ ${#sequences[@]} -eq 0 ]] && sequences=(V1_01_easy)
base=${EUROC_BASE_URL:-http://robotics.ethz.ch/~asl-datasets/ijrr_euroc_mav_dataset}

mkdir -p "$target"
for seq in "${sequences[@]}"; do
    case $seq in
        MH_0[1-5]_*) room=machine_hall ;;
        V1_0[1-3]_*) room=vicon_room1 ;;
        V2_0[1-3]_*) room=vicon_room2 ;;
        *) echo "error: '$seq' is not a EuRoC sequence name like V1_01_easy" >&2; exit 2 ;;
    esac
    if [[ -d $target/$seq/mav0 ]]; then
        echo "$seq: already in $target, skipping"
        continue
    fi
    url="$base/$room/$seq/$seq.zip"
    echo "downloading $url"
    curl -fL --retry 3 -o "$target/$seq.zip.part" "$url"
    mv "$target/$seq.zip.part" "$target/$seq.zip"
    mkdir -p "$target/$seq"
    unzip -q "$target/$seq.zip" -d "$target/$seq"
    rm "$target/$seq.zip"
done
echo "done: ${sequences[*]} in $target"
