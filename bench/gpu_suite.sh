#!/usr/bin/env bash
# The GPU suite in one device call, at 640x480: GPU tests, both trackers side by side (TUM fr3/teddy
# subset, synthetic room), the SLAM live at the camera's rate and in lockstep, the gsplat renderer
# benchmark, a profile of two Gauss-Newton frames, then tracking and the room live with the ICP
# through torch.compile (render.compile) as time allows. Results go under $OUT.
#
#   bash bench/gpu_suite.sh prepare [FRAMES]   # here: wheels into .whl/, a TUM subset into .gpu_data/
#   bash bench/gpu_suite.sh run                # there (the device tool), carrying .whl and .gpu_data
#   bash bench/gpu_suite.sh prepare-ros        # here: the ROS 2 wheels for Python 3.12 into .whl_ros/
#   bash bench/gpu_suite.sh ros                # there, a second call carrying .whl_ros: slam_node on CUDA
#   bash bench/gpu_suite.sh smoke              # here, on the CPU: the same steps at toy sizes
#   bash bench/gpu_suite.sh longrun [K=V...]   # there, carrying .whl: 2,000 looping frames at 640x480 (memory
#                                              # held over a long run) beside the room's 200 frames, both with
#                                              # the given config overrides (and the 200 again without them);
#                                              # $SGS_GPU_LONGRUN_TAG names the result files, and
#                                              # SGS_GPU_LONGRUN_SIDE=0 runs the long run alone;
#                                              # `longrun-smoke` runs it here at toy sizes
#
# The device call sends the checkout plus carried folders, 64 MiB in all. .whl holds gsplat and the
# run-time dependencies the GPU image may lack (matplotlib and its dependencies, tqdm: ~31 MB with
# gsplat); the TUM subset is FRAMES colour+depth pairs (default 30, ~20 MB); prepare prints the
# total. The ROS 2 wheels (~45 MB) do not fit beside them: the slam_node CUDA test, which skips in
# `run`, has its own call (`ros`). The machine
# allows 10 minutes per call: every step has its own time limit within the suite's 570 s, in order of
# importance, and the suite goes on after a failure, so what finished still comes back. The figures to copy into BENCHMARKS.md are in
# $OUT/BENCHMARKS-gpu.md (sections in the usual format, device named) and $OUT/summary.txt.
set -uo pipefail
cd "$(dirname "$0")/.."
mode=${1:-run}

PIP_312=(python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp
         --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64
         --platform any)

die() { echo "gpu_suite: $*" >&2; exit 1; }

carried_mib() {  # the checkout's tracked files plus the given folders, MiB
  local bytes
  bytes=$(( $(du -sb "$@" | awk '{s += $1} END {print s}') + $(git ls-files -z | xargs -0 du -b | awk '{s += $1} END {print s}') ))
  echo "carried with the checkout: $((bytes / 1048576)) MiB of 64"
  [ "$bytes" -lt $((64 * 1048576)) ] || { echo "too much to carry" >&2; exit 1; }
}

prepare_ros() {
  rm -rf .whl_ros && mkdir -p .whl_ros
  .venv/bin/pip list --format=freeze 2>/dev/null | grep -E '^ros-' > .whl_ros/ros-requirements.txt
  [ -s .whl_ros/ros-requirements.txt ] || die "no ROS wheels in .venv (run make setup first)"
  "${PIP_312[@]}" -d .whl_ros -r .whl_ros/ros-requirements.txt || die "downloading the ROS wheels failed"
  carried_mib .whl_ros
}

prepare() {
  local frames=${1:-30}
  local pip=("${PIP_312[@]}")
  rm -rf .whl .gpu_data && mkdir -p .whl .gpu_data
  "${pip[@]}" -d .whl gsplat==1.5.3 || die "downloading gsplat failed"
  # plots and progress bars (sgs_slam_core needs them); numpy, torch, opencv, pyyaml are in the image
  "${pip[@]}" -d .whl matplotlib==3.11.2 contourpy cycler fonttools kiwisolver pillow pyparsing python-dateutil \
    packaging six tqdm || die "downloading matplotlib and tqdm failed"
  .venv/bin/python bench/tum_subset.py ../shared/data/tum_fr3_teddy .gpu_data/tum_fr3_teddy --frames "$frames" \
    || die "making the TUM subset failed"
  carried_mib .whl .gpu_data
}

DEADLINE=$((SECONDS + ${SGS_GPU_SUITE_BUDGET_S:-570}))  # the device call's 600 s, less the copy back

step() {  # step NAME SECONDS COMMAND...: run with a time limit (and the suite's), log to $OUT/NAME.log
  local name=$1 limit=$2
  shift 2
  local left=$((DEADLINE - SECONDS - 5))
  if [ "$left" -lt 20 ]; then
    echo "$name: skipped, the suite's time is up" | tee -a "$OUT/summary.txt"
    return 0
  fi
  [ "$limit" -gt "$left" ] && limit=$left
  local t0=$SECONDS
  timeout "$limit" "$@" > "$OUT/$name.log" 2>&1
  local rc=$?
  echo "$name: exit $rc after $((SECONDS - t0)) s" | tee -a "$OUT/summary.txt"
  return 0
}

install_wheels() {  # install_wheels FOLDER: its wheels into a venv over the image's packages; PY becomes its python
  ls "$1"/*.whl > /dev/null 2>&1 || return 0
  # installed by the venv's python (running the image's pip), so every part of a wheel lands in the
  # venv's scheme: the ROS wheels' start-up hook (a .pth file) in site-packages, their shared
  # libraries in <venv>/lib (pip --target drops those, and rclpy then does not import)
  $PY -m venv --system-site-packages --without-pip /tmp/sgs_venv
  # the image's python may itself be a venv, whose packages a nested venv does not see: a .pth names them
  $PY -c "import site; print('\n'.join(site.getsitepackages()))" \
    > "$(/tmp/sgs_venv/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/image_packages.pth"
  /tmp/sgs_venv/bin/python -m pip install -q --no-index --no-deps "$1"/*.whl >> "$OUT/pip.log" 2>&1
  PY=/tmp/sgs_venv/bin/python
}

run_ros() {  # slam_node in-process on CUDA for a few frames (the ROS wheels travel alone: 45 MB)
  : "${OUT:=$PWD/gpu_out}"
  mkdir -p "$OUT"
  export PYTHONPATH=$PWD ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
  : > "$OUT/summary.txt"
  install_wheels .whl_ros
  step ros_tests 400 $PY -m pytest -q -rs test/devices/test_cuda.py -k slam_node
}

begin_suite() {  # begin_suite DEVICE: $OUT, the environment, the machine in summary.txt, the wheels on CUDA
  : "${OUT:=$PWD/gpu_out}"
  mkdir -p "$OUT"
  export SGS_SLAM_BENCH_OUT=$OUT/BENCHMARKS-gpu.md TORCH_EXTENSIONS_DIR=${TORCH_EXTENSIONS_DIR:-/tmp/torch_ext}
  export MAX_JOBS=${MAX_JOBS:-16} PYTHONPATH=$PWD XDG_CACHE_HOME=/tmp/sgs_cache
  : > "$OUT/summary.txt"
  { nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null || echo "no GPU";
    $PY -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())"; } | tee -a "$OUT/summary.txt"
  if [ "$1" = cuda ]; then install_wheels .whl; fi
}

run_suite() {
  local device=$1 scale=$2 room_frames=$3 tum_frames=$4
  begin_suite "$device"
  local build_pid=""
  if [ "$device" = cuda ]; then  # gsplat compiles (1-2 min) while the scene is generated
    ($PY -c "from gsplat.cuda._backend import _C" > "$OUT/gsplat_build.log" 2>&1; echo "gsplat build exit $?" >> "$OUT/gsplat_build.log") &
    build_pid=$!
  fi
  local w=$((640 / scale)) h=$((480 / scale)) room=/tmp/sgs_room_$scale
  step synth 300 $PY -m sgs_slam_core.cli synth "$room" --preset room --width $w --height $h --frames "$room_frames" --overwrite
  [ -n "$build_pid" ] && wait "$build_pid"
  local tests=(test/devices/test_cuda.py)
  [ "$device" = cuda ] && tests+=(test/render/test_gsplat_parity.py)
  step gpu_tests 150 $PY -m pytest -q -rs "${tests[@]}"
  local sets=(--device "$device" --no-append)
  [ "$device" = cuda ] && sets=(--device cuda)
  local tum=.gpu_data/tum_fr3_teddy
  if [ -d "$tum" ]; then  # both trackers on the same frames and maps, then each in its own run
    step tracking_tum 150 $PY bench/bench_tracking.py "$tum" --preset tum "${sets[@]}" --max-frames "$tum_frames" \
      --downscale "$scale" --trackers adam gauss_newton
  fi
  step slam_room_rt30 90 $PY bench/bench_slam.py "$room" --preset synthetic "${sets[@]}" --realtime 30 --out "$OUT/run_room_rt30"
  if [ -d "$tum" ]; then
    step slam_tum_rt 60 $PY bench/bench_slam.py "$tum" --preset tum "${sets[@]}" --max-frames "$tum_frames" \
      --downscale "$scale" --realtime --out "$OUT/run_tum_rt"
  fi
  step slam_room 220 $PY bench/bench_slam.py "$room" --preset synthetic "${sets[@]}" --out "$OUT/run_room"
  # the preset's live tracker judges the depth-ICP start; the full solve beside it, for the time ratio
  step tracking_room 90 $PY bench/bench_tracking.py "$room" --preset synthetic "${sets[@]}" --max-frames 30 \
    --downscale 1 --trackers adam gauss_newton "gauss_newton:gauss_newton.iterations=[6,4,3]" --skip-runs
  if [ "$device" = cuda ]; then
    step render 60 $PY bench/bench_render.py --backend gsplat
  fi
  if [ -d "$tum" ]; then  # where a Gauss-Newton frame's time goes: two frames under torch.profiler, mapping cut to 10 steps
    step profile_tum 100 $PY bench/bench_slam.py "$tum" --preset tum "${sets[@]}" --max-frames 12 --downscale "$scale" \
      --set tracking.method=gauss_newton --set mapping.iterations=10 --profile 2 --profile-warmup 9 --out "$OUT/run_profile"
  fi
  # last, as the suite's time allows: the ICP through torch.compile (render.compile), tracking and the room live
  if [ -d "$tum" ]; then
    step tracking_tum_compiled 150 $PY bench/bench_tracking.py "$tum" --preset tum "${sets[@]}" --max-frames "$tum_frames" \
      --downscale "$scale" --trackers gauss_newton --set render.compile=true --skip-runs
  fi
  step slam_room_rt30_compiled 120 $PY bench/bench_slam.py "$room" --preset synthetic "${sets[@]}" --realtime 30 \
    --set render.compile=true --out "$OUT/run_room_rt30_compiled"
  for run in "$OUT"/run_*; do  # keep the small files; maps and renders stay behind
    [ -d "$run" ] && find "$run" -maxdepth 1 -type f \( -name '*.sgsmap' -o -name '*.ply' \) -delete
  done
  echo "done: see $OUT/summary.txt$([ "$device" = cuda ] && echo " and $OUT/BENCHMARKS-gpu.md")"
}

run_longrun() {  # run_longrun DEVICE WIDTH HEIGHT FRAMES LOOP_FRAMES ROOM_FRAMES [KEY=VALUE...]
  local device=$1 w=$2 h=$3 frames=$4 loop=$5 room_frames=$6
  shift 6
  local sets=() tag=${SGS_GPU_LONGRUN_TAG:-}
  for kv in "$@"; do sets+=(--set "$kv"); done
  begin_suite "$device"
  local build_pid=""
  if [ "$device" = cuda ]; then  # gsplat compiles while the room renders; a run importing it earlier fails
    ($PY -c "from gsplat.cuda._backend import _C" > "$OUT/gsplat_build.log" 2>&1; echo "gsplat build exit $?" >> "$OUT/gsplat_build.log") &
    build_pid=$!
  fi
  local room=/tmp/sgs_room_longrun
  local with_side=${SGS_GPU_LONGRUN_SIDE:-1}
  [ "$with_side" != 0 ] && step synth 200 $PY -m sgs_slam_core.cli synth "$room" --preset room --width "$w" \
    --height "$h" --frames "$room_frames" --overwrite
  [ -n "$build_pid" ] && wait "$build_pid"
  # beside the long run: the room's standard 200 frames under the same settings (peak GPU memory,
  # accuracy), then, where settings were given, without them (the baseline from the same call);
  # SGS_GPU_LONGRUN_SIDE=0 leaves the long run alone on the machine (its time per frame undisturbed)
  local side=""
  if [ "$with_side" != 0 ]; then
    (step slam_room_set 300 $PY bench/bench_slam.py "$room" --preset synthetic --device "$device" "${sets[@]}" \
       --out "$OUT/run_room_set"
     [ ${#sets[@]} -gt 0 ] && step slam_room_base 300 $PY bench/bench_slam.py "$room" --preset synthetic \
       --device "$device" --out "$OUT/run_room_base") &
    side=$!
  fi
  # the long run gets what is left; on SIGTERM (timeout) it stops and still reports what it measured
  step longrun $((DEADLINE - SECONDS - 40)) $PY bench/bench_longrun.py --width "$w" --height "$h" --frames "$frames" \
    --loop-frames "$loop" --device "$device" --mapping-iterations 10 --set tracking.method=gauss_newton "${sets[@]}" \
    --every 20 ${tag:+--tag "$tag"}
  [ -n "$side" ] && wait "$side"
  cp bench/results/longrun_"${w}x${h}"_* "$OUT/" 2>/dev/null
  for run in "$OUT"/run_*; do
    [ -d "$run" ] && find "$run" -maxdepth 1 -type f \( -name '*.sgsmap' -o -name '*.ply' \) -delete
  done
  echo "done: see $OUT/summary.txt"
}

case "$mode" in
  prepare) prepare "${2:-30}" ;;
  prepare-ros) prepare_ros ;;
  ros) PY=${PY:-python3} run_ros ;;
  run) PY=${PY:-python3} run_suite cuda 1 200 "${SGS_GPU_TUM_FRAMES:-30}" ;;
  smoke) PY=${PY:-.venv/bin/python} OUT=${OUT:-/tmp/gpu_suite_smoke} run_suite cpu 8 6 6 ;;
  longrun) PY=${PY:-python3} run_longrun cuda 640 480 2000 60 200 "${@:2}" ;;
  longrun-smoke) PY=${PY:-.venv/bin/python} OUT=${OUT:-/tmp/gpu_longrun_smoke} run_longrun cpu 64 48 30 6 6 "${@:2}" ;;
  *) echo "usage: bash bench/gpu_suite.sh prepare [FRAMES] | run | prepare-ros | ros | smoke | longrun [K=V...] | longrun-smoke [K=V...]" >&2; exit 2 ;;
esac
