#!/usr/bin/env bash
# The GPU checks of one lent device machine (docs/benchmarks.md, "GPU backend"), as one call:
#   run(command="bash benchmarks/gpu_device.sh", carry=[".gl", ".whl"], timeout_s=600)
# .gl holds the Vulkan/GL loaders (.deb) and .whl the wheels the machine's image lacks
# (wgpu, cffi, pycparser, rendercanvas, laspy, lazrs, plyfile), fetched here as the device
# tool's README says (both folders listed in .git/info/exclude):
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#     --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d .whl \
#     wgpu==0.32.0 cffi==2.1.1 pycparser==3.12 rendercanvas==2.7.2 laspy==2.7.0 lazrs==0.8.2 plyfile==1.1.5
# Everything printed goes to $OUT/log too. Each step has its own time
# limit, so one that hangs costs only its share of the lease; all of them together exceed the
# 600 s a call may run: pick some with STEPS (the first session's run without "early": 334 s,
# its brute-force step 205 s of them).
set -u
LOG=${OUT:-/tmp}/log
exec > >(tee -a "$LOG") 2>&1
PY=${PY:-python3}  # the image's Python (PY=.venv/bin/python to try the script here, with the wheels already installed)
if [ -z "${NO_CARRY:-}" ]; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
    $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
fi
icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
[ -f "$icd" ] && export VK_DRIVER_FILES=$icd
egl=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
[ -f "$egl" ] && export __EGL_VENDOR_LIBRARY_FILENAMES=$egl
export PYTHONPATH=/tmp/site:$PWD/src PYTHONUNBUFFERED=1 NUMBA_CACHE_DIR=/tmp/nbc
# STEPS: the steps to run (all by default), e.g. STEPS="adapter early" bash benchmarks/gpu_device.sh
STEPS=${STEPS:-adapter brute early exact tests uploads frames}
step() {
    local name=$1 limit=$2; shift 2
    case " $STEPS " in *" $name "*) ;; *) return 0 ;; esac
    echo "=== $(date -u +%T) $* (limit ${limit}s)"; timeout "$limit" "$@"; echo "=== exit $?"
}
nvidia-smi -L; lscpu | grep 'Model name'; nproc
step adapter 60 $PY -c "
import numba, numpy, wgpu
print('numpy', numpy.__version__, 'numba', numba.__version__, 'wgpu', wgpu.__version__)
for a in wgpu.gpu.enumerate_adapters_sync():
    print(a.info['device'], a.info['backend_type'], a.info['adapter_type'], 'storage binding', a.limits['max-storage-buffer-binding-size'], 'buffer', a.limits['max-buffer-size'], sorted(f for f in a.features if 'int64' in f))
from gigapoint.backends.wgpu import WgpuBackend
print(WgpuBackend(require_hardware=True).describe())
"
# brute force, overview and close-up (issue #6): 100 M and 500 M points, the CPU backend on every core beside it
step brute ${BRUTE_S:-250} $PY benchmarks/bench_wgpu.py --points ${BRUTE_POINTS:-100M 500M} --views overview closeup --gpu-memory 100G --repeats 10 --fallback
# the early-depth test's variants and front-to-back batch order against the shipped pass
step early ${EARLY_S:-300} $PY benchmarks/gpu_early_depth.py --points ${EARLY_POINTS:-100M 500M} --gpu-memory 100G --repeats 10 ${EARLY_FLAGS---fallback --front-to-back}
# the wgpu visibility buffer against the CPU's, products kept and left to the driver to fuse
step exact ${EXACT_S:-90} $PY benchmarks/gpu_exactness.py --timing 10M
# the GPU tier on real hardware (CI has lavapipe only, whose compiler never fuses a * b + c:
# the NVIDIA driver's fusing showed only here, exact.wgsl)
step tests ${TESTS_S:-140} $PY -m pytest -q -rf -p no:cacheprovider --timeout 120 tests/unit/test_wgpu_backend.py tests/unit/test_wgpu_lod.py \
    tests/unit/test_wgpu_passes.py tests/unit/test_wgpu_stereo.py tests/unit/test_transparency_wgpu.py tests/unit/test_live_wgpu.py
# frames while the progressive octree loads: changed chunks sent merged across small gaps, and one write a run
step uploads ${UPLOADS_S:-240} $PY benchmarks/bench_gpu_uploads.py --points ${UPLOADS_POINTS:-10M} --rounds 2
# the progressive octree drawn by the GPU while it loads, 1920x1080, 10 M budget (issue #18)
step frames ${FRAMES_S:-90} $PY benchmarks/bench_progressive.py --points ${FRAMES_POINTS:-10M} --parts frames --backend wgpu
echo "=== $(date -u +%T) done"
