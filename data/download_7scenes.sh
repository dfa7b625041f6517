#!/usr/bin/env bash
# Download Microsoft 7-Scenes (non-commercial research use, see the licence on the download page:
# https://www.microsoft.com/en-us/research/project/rgb-d-dataset-7-scenes/) into TARGET.
#   usage: data/download_7scenes.sh TARGET [SCENE ...]
#   scenes: chess fire heads office pumpkin redkitchen stairs   (default: chess)
# Each scene ends up as TARGET/<scene>/seq-XX/frame-XXXXXX.{color.png,depth.png,pose.txt}, ready for
# `gsslam run TARGET/chess/seq-01 --dataset 7scenes`.
set -euo pipefail

if [[ $# -lt 1 ]]; then
    echo "usage: $0 TARGET [SCENE ...]   (default: chess)" >&2
    exit 2
fi
target=$1
shift
scenes=("$@")
[[ ${#scenes[@]} -eq 0 ]] && scenes=(chess)
base=${SEVENSCENES_BASE_URL:-https://download.microsoft.com/download/2/8/5/28564B23-0828-408F-8631-23B1EFF1DAC8}

mkdir -p "$target"
for scene in "${scenes[@]}"; do
    case $scene in
        chess | fire | heads | office | pumpkin | redkitchen | stairs) ;;
        *) echo "error: unknown 7-Scenes scene '$scene'" >&2; exit 2 ;;
    esac
    if compgen -G "$target/$scene/seq-*/frame-000000.color.png" > /dev/null; then
        echo "$scene: already in $target, skipping"
        continue
    fi
    echo "downloading $base/$scene.zip"
    curl -fL --retry 3 -o "$target/$scene.zip.part" "$base/$scene.zip"
    mv "$target/$scene.zip.part" "$target/$scene.zip"
    unzip -q -o "$target/$scene.zip" -d "$target"
    rm "$target/$scene.zip"
    # each scene zip holds one zip per sequence
    for seqzip in "$target/$scene"/seq-*.zip; do
        [[ -e $seqzip ]] || continue
        unzip -q -o "$seqzip" -d "$target/$scene"
        rm "$seqzip"
    done
done
echo "done: ${scenes[*]} in $target"
