#!/usr/bin/env bash
# GPU check (docs/rasterizer.md): the `gpu`-marked tests, then a TUM fr3/teddy 200-frame monocular run
# with the CUDA rasterizer (gsplat), both recorded into one folder. For a machine with CUDA, after
#   pip install torch==2.13.0 -e ".[dev,cuda]"
# (a CUDA build of torch; gsplat compiles its kernels at first use unless a prebuilt wheel matching
# torch and CUDA is installed, so the first call below may take minutes, or fail without nvcc).
#
#   scripts/gpu_check.sh [OUT_DIR] [TEDDY_SEQUENCE]
#
# OUT_DIR (default runs/gpu_check) receives env.txt, gpu_tests.log/.xml, teddy200_mono_gsplat/ (the run:
# metrics.json records mapper.rasterizer_backend), eval.json and summary.txt. Exit status 0 only when
# the tests passed, none of them skipped, and the run used gsplat.
set -uo pipefail
cd "$(dirname "$0")/.."

OUT=${1:-runs/gpu_check}
SEQ=${2:-}
if [ -z "$SEQ" ]; then
  for cand in ../shared/data/rgbd_dataset_freiburg3_teddy shared/data/rgbd_dataset_freiburg3_teddy; do
    [ -d "$cand" ] && SEQ=$cand && break
  done
fi
if [ -z "$SEQ" ] || [ ! -d "$SEQ" ]; then
  echo "gpu_check: TUM fr3/teddy not found; pass its folder as the second argument" >&2
  exit 2
fi
mkdir -p "$OUT"

# 1. the machine, and a preflight that fails early (and says why) without CUDA or gsplat
{
  date -u
  nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv 2>&1 || true
  python3 - <<'EOF'
import time

import torch

print("torch", torch.__version__, "cuda", torch.version.cuda, "available", torch.cuda.is_available())
if not torch.cuda.is_available():
    raise SystemExit("gpu_check: torch sees no CUDA device (install a CUDA build of torch)")
try:
    import gsplat
except ImportError:
    raise SystemExit("gpu_check: gsplat missing: pip install -e '.[cuda]'") from None
print("gsplat", gsplat.__version__)
from gsslam.mapping.rasterize import render

t0 = time.perf_counter()
dev = torch.device("cuda")
n = 16
means = torch.randn(n, 3, device=dev) * 0.2 + torch.tensor([0.0, 0.0, 2.0], device=dev)
quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]], device=dev).repeat(n, 1)
scales = torch.full((n, 3), 0.05, device=dev)
K = torch.tensor([[40.0, 0, 31.5], [0, 40.0, 23.5], [0, 0, 1]], device=dev)
out = render(means, quats, scales, torch.full((n,), 0.8, device=dev), torch.rand(n, 3, device=dev),
             torch.eye(4, device=dev), K, 64, 48, backend="gsplat")
torch.cuda.synchronize()
print(f"gsplat first render (includes any kernel build): {time.perf_counter() - t0:.1f} s,",
      f"alpha max {float(out.alpha.max()):.2f}")
EOF
} > "$OUT/env.txt" 2>&1
preflight=$?
cat "$OUT/env.txt"
if [ $preflight -ne 0 ]; then
  echo "gpu_check: preflight failed (see $OUT/env.txt)" >&2
  exit 2
fi

# 2. the gpu-marked tests (-rs lists any skip with its reason)
python3 -m pytest -m gpu -q -rs tests --junitxml "$OUT/gpu_tests.xml" 2>&1 | tee "$OUT/gpu_tests.log"
tests_rc=${PIPESTATUS[0]}

# 3. teddy 200, monocular, map on the GPU with gsplat
RUN="$OUT/teddy200_mono_gsplat"
gsslam run "$SEQ" --dataset tum --mode mono --max-frames 200 --out "$RUN" --no-progress \
  --set mapper.device=cuda --set mapper.rasterizer=gsplat 2>&1 | tee "$OUT/run.log"
run_rc=${PIPESTATUS[0]}
if [ $run_rc -eq 0 ]; then
  gsslam eval "$SEQ/groundtruth.txt" "$RUN/trajectory.tum" --align sim3 --json > "$OUT/eval.json"
fi

# 4. one summary, and the verdict
python3 - "$OUT" "$RUN" "$tests_rc" "$run_rc" <<'EOF' | tee "$OUT/summary.txt"
import json
import re
import sys
from pathlib import Path

out, run, tests_rc, run_rc = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
log = (out / "gpu_tests.log").read_text()
final = [ln for ln in log.splitlines() if re.search(r"\d+ (passed|failed|skipped|error)", ln)]
skipped = bool(re.search(r"\d+ skipped", final[-1])) if final else True
print("gpu tests:", final[-1].strip() if final else "no result line", f"(exit {tests_rc})")
ok = tests_rc == 0 and not skipped
if run_rc == 0 and (run / "metrics.json").is_file():
    m = json.loads((run / "metrics.json").read_text())
    mp = m.get("mapper") or {}
    backend = mp.get("rasterizer_backend")
    ate = (m.get("ate") or {}).get("rmse_m")
    print("teddy 200 mono: rasterizer", backend, "| ATE rmse (sim3, m)", ate,
          "| PSNR keyframes", mp.get("psnr_keyframes"), "| FPS", m.get("fps"))
    ok = ok and backend == "gsplat"
else:
    print(f"teddy 200 mono: run failed (exit {run_rc}), see run.log")
    ok = False
print("verdict:", "OK" if ok else "FAILED")
sys.exit(0 if ok else 1)
EOF
exit "${PIPESTATUS[0]}"
