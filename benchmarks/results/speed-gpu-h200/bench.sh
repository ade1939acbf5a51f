#!/bin/bash
# usage: bash .gpu/bench.sh TAG FRAMES   (run on the device, after install.sh)
tag=$1; frames=${2:-300}
export PYTHONPATH=/root/site:$PWD PYTHONUNBUFFERED=1
cd "$(dirname "$0")/.."
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee $OUT/$tag-nvidia.txt
set -o pipefail
s=$(date +%s)
( time python3 -m rose_usd.cli bench speed all --frames $frames --size 640x480 -o /root/speed-$tag ) 2>&1 | tee $OUT/$tag.log
rc=$?
echo "rc=$rc wall=$(( $(date +%s) - s ))s" | tee -a $OUT/$tag.log
cp /root/speed-$tag/speed-all.json $OUT/$tag-speed-all.json 2>/dev/null
cp /root/speed-$tag/runs/all-${frames}x640x480.json $OUT/$tag-worker.json 2>/dev/null
cp /root/speed-$tag/runs/all-${frames}x640x480/report/gate.json $OUT/$tag-gate.json 2>/dev/null
python3 - "$tag" "$frames" <<'PY' 2>&1 | tee $OUT/$tag-layers.txt
import sys, glob, json
sys.path.insert(0, "/root/site")
from pxr import Sdf
tag, n = sys.argv[1], sys.argv[2]
for f in sorted(glob.glob(f"/root/speed-{tag}/runs/all-{n}x640x480/layers/*.usda")):
    d = dict(Sdf.Layer.OpenAsAnonymous(f, metadataOnly=True).customLayerData)
    print(f, json.dumps(d, default=str)[:1500])
PY
ls ~/.cache/warp 2>/dev/null | head; du -sh ~/.cache/warp 2>/dev/null
