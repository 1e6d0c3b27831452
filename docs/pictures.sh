#!/usr/bin/env bash
# The camera page's pictures (docs/camera.md), made on this machine from the
# shared KITTI images and scans with the shared network: the segmentation of
# kitti00 frame 0 laid over its image, and the map of kitti00 frames 0-9
# built from the camera's labels, exported as PLY and drawn from above.
#
# They are derived from KITTI and SemanticKITTI (CC BY-NC-SA): they go to
# docs/pictures/, which git ignores; the project keeps KITTI's data and
# what is made of it out of the repository.
set -euo pipefail
cd "$(dirname "$0")/.."
data=${COSEM_DATA:-../shared/data}
model=${COSEM_MODEL:-$data/../models/espnetv2-cityscapes-s2.0-512x1024.onnx}
out=docs/pictures
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

cargo build --release --quiet -p cosem-host --features segment
cosem=target/release/cosem
mkdir -p "$out"
# The three commands: segment, label, map (then export and draw).
$cosem segment --model "$model" --images "$data/kitti00/image_2" --out "$tmp/seg" --overlay
$cosem label --data "$data/kitti00" --seg "$tmp/seg" --out "$tmp/k00-camera"
$cosem map --data "$tmp/k00-camera" --frames 0:10 -o "$tmp/k00-camera.cmap"
$cosem export ply "$tmp/k00-camera.cmap" --output "$out/kitti00-camera-map.ply"
python3 docs/render_ply.py "$out/kitti00-camera-map.ply" "$out/kitti00-camera-map.png"
cp "$tmp/seg/000000.overlay.png" "$out/kitti00-000000-overlay.png"
echo "pictures in $out/ (CC BY-NC-SA, derived from KITTI and SemanticKITTI: keep them out of the repository)"
