#!/usr/bin/env bash
# The GPU check: `pfx bench --backend jax` and the JAX backend's validity tests, in one prepared
# run of under 9 minutes, on a borrowed GPU machine without network access, or on any machine.
#
#   make gpu-check                    # or: bash examples/gpu_check.sh
#   bash examples/gpu_check.sh --download-wheels   # here, with a network: fetch the wheels the lent
#                                                  # machine lacks into .whl/ (then carry .whl)
#
# Run from the repository root. What it does:
# 1. Says on its first line whether it sees an NVIDIA GPU (nvidia-smi); without one it still runs,
#    on JAX's CPU build, with the bench's --quick sizes (a CPU would take far longer on the full ones).
# 2. Where a folder of wheels is present (.whl/ by default: PFX_WHEELS), installs them with no
#    network and no dependencies into a private folder put first on PYTHONPATH, and puts the
#    repository itself on PYTHONPATH, so that `python -m pfx` runs this tree (a GPU machine seen
#    with JAX, NumPy, numba, SciPy, pandas and matplotlib installed lacked pydantic, pydantic-core,
#    annotated-types, typing-inspection, typing-extensions and arviz-stats: docs/backends.md).
# 3. Runs `pfx bench --backend jax` (PFX_BENCH_ARGS, default "--repeats 2 --budget 10" on a GPU,
#    "--quick --repeats 2" without one) with XLA_PYTHON_CLIENT_PREALLOCATE=false (JAX takes device
#    memory as it needs it); its progress lines go to bench.txt too (the table comes at the end).
# 4. Runs the JAX backend's tests (PFX_GPU_TESTS: pytest arguments, default the files below; a
#    named file that this tree lacks is left out, and said so).
# 5. On a GPU, times pomp's two models (cholera at N = 1000 and 5000, measles at N = 2000) on the
#    jax backend in batches of 16 and 48 runs: seconds per run and replicates per second once
#    compiled (examples/benchmarks/pomp_speed_session.py; PFX_POMP_ARGS, PFX_POMP_TIMEOUT). Where
#    pypomp imports (its wheel among the carried ones), pypomp's filter too, 64 replicates a call.
# Everything goes to $OUT (the GPU machine's folder that comes back), else ./gpu-check-output:
# gpu-check.txt (this script's own lines), bench.txt, tests.txt, pomp.txt. Exit status: 0 when the
# bench, the tests and the pomp timings passed, else the first failure's.
#
# Variables: PFX_PYTHON (default .venv/bin/python where it exists, else python3), PFX_WHEELS,
# PFX_BENCH_ARGS, PFX_GPU_TESTS, PFX_POMP_ARGS, PFX_BENCH_TIMEOUT, PFX_TESTS_TIMEOUT and PFX_POMP_TIMEOUT
# (seconds, default 230, 120 and 190: the whole check stays under 10 minutes, the time a lent GPU
# machine gives one command; on an H200 the bench's filter table took about 3 minutes, its PMMH
# part more, the tests 104 s, measles on the jax backend 1.2 s a run in a batch of 64).

set -u
cd "$(dirname "$0")/.." || exit 2
# The packages such a machine was seen to lack (Python 3.12, x86-64; docs/backends.md).
MISSING="pydantic pydantic-core annotated-types typing-inspection typing-extensions arviz-stats"
# pypomp, for its filter timed beside pfx's in the pomp step (pure Python; its needs are on such a machine)
PEERS="pypomp==1.1.0"
if [ "${1:-}" = --download-wheels ]; then
    # shellcheck disable=SC2086
    python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --platform manylinux2014_x86_64 --platform manylinux_2_17_x86_64 -d "${PFX_WHEELS:-.whl}" $MISSING $PEERS || exit 2
    [ "${PFX_WHEELS:-.whl}" = .whl ] && ! grep -qx '/.whl/' "$(git rev-parse --git-common-dir 2>/dev/null)/info/exclude" \
        2>/dev/null && echo "gpu-check: add /.whl/ to .git/info/exclude, so that the wheels stay out of git"
    exit 0
fi
out=${OUT:-./gpu-check-output}
mkdir -p "$out"
log="$out/gpu-check.txt"
: > "$log"
say() { echo "gpu-check: $*" | tee -a "$log"; }

if command -v nvidia-smi >/dev/null 2>&1 && gpus=$(nvidia-smi --query-gpu=name,memory.total,driver_version \
        --format=csv,noheader 2>/dev/null) && [ -n "$gpus" ]; then
    gpu=yes
    say "GPU found: ${gpus//$'\n'/; }"
else
    gpu=no
    say "no GPU found (nvidia-smi absent or it lists none): running on the CPU, bench at --quick sizes"
fi

python=${PFX_PYTHON:-}
if [ -z "$python" ]; then
    if [ -x .venv/bin/python ]; then python=.venv/bin/python; else python=python3; fi
fi
wheels=${PFX_WHEELS:-.whl}
if compgen -G "$wheels/*.whl" >/dev/null; then
    site=$(mktemp -d "${TMPDIR:-/tmp}/pfx-gpu-check-site.XXXXXX")
    if ! "$python" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target "$site" \
            "$wheels"/*.whl >>"$log" 2>&1; then
        say "the wheels in $wheels/ did not install (see $log)"
        exit 2
    fi
    export PYTHONPATH="$site:$PWD${PYTHONPATH:+:$PYTHONPATH}"
    say "installed $(ls "$wheels"/*.whl | wc -l) wheels from $wheels/ into $site"
else
    export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
fi
export XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1
say "python: $("$python" -c 'import sys; print(sys.executable, sys.version.split()[0])' 2>&1)"
if ! devices=$("$python" -c 'import jax; print(jax.__version__, jax.default_backend(), jax.devices())' 2>&1); then
    say "JAX does not import: ${devices##*$'\n'}"
    exit 2
fi
say "jax: $devices"
case "$devices" in
    *" gpu "*|*" cuda "*) ;;
    *) [ "$gpu" = yes ] && say "an NVIDIA GPU is there but JAX does not use it (JAX's CPU build?)" ;;
esac

if [ "$gpu" = yes ]; then default_args="--repeats 2 --budget 10"; else default_args="--quick --repeats 2"; fi
bench_args=${PFX_BENCH_ARGS-$default_args}
limit=${PFX_BENCH_TIMEOUT:-230}
say "pfx bench --backend jax $bench_args (at most $limit s) > $out/bench.txt"
started=$SECONDS
# shellcheck disable=SC2086  # the arguments are words
timeout "$limit" "$python" -m pfx bench --backend jax $bench_args >"$out/bench.txt" 2>&1
bench_status=$?
if [ "$bench_status" -eq 124 ]; then
    say "bench: stopped at $limit s, before its table (printed at the end): rerun with PFX_BENCH_ARGS=--quick"
else
    say "bench: exit $bench_status after $((SECONDS - started)) s"
fi

tests=()
for word in ${PFX_GPU_TESTS:-tests/test_jax_backend.py tests/test_bench_jax.py tests/test_kernel_replay.py}; do
    if [[ $word == -* || -e ${word%%::*} ]]; then tests+=("$word"); else say "not in this tree, left out: $word"; fi
done
test_status=0
limit=${PFX_TESTS_TIMEOUT:-120}
if [ ${#tests[@]} -gt 0 ]; then
    say "pytest ${tests[*]} (at most $limit s) > $out/tests.txt"
    started=$SECONDS
    # XLA_FLAGS set (empty unless given): the suite's own CPU compile settings stay out (tests/conftest.py)
    XLA_FLAGS=${XLA_FLAGS-} timeout "$limit" "$python" -m pytest -q -p no:cacheprovider -o addopts=-ra "${tests[@]}" \
        >"$out/tests.txt" 2>&1
    test_status=$?
    say "tests: exit $test_status after $((SECONDS - started)) s: $(tail -n 1 "$out/tests.txt")"
else
    say "no test to run"
fi

# pomp's models on the jax backend: seconds per run and replicates per second once compiled
# (examples/benchmarks/pomp_speed_session.py without pypomp); on a GPU only, unless PFX_POMP_ARGS
# is given (on a CPU the measles model alone takes minutes: the session script's table has it).
pomp_status=0
if [ "$gpu" = yes ] || [ -n "${PFX_POMP_ARGS:-}" ]; then
    pomp_args=${PFX_POMP_ARGS:-"--no-numpy --models measles cholera --jax measles cholera --trials 16"}
    limit=${PFX_POMP_TIMEOUT:-190}
    # pypomp beside pfx on the same card, where its wheel came along: its calls of 64 replicates side by side
    if [ -z "${PFX_POMP_ARGS:-}" ] && "$python" -c 'import pypomp' >/dev/null 2>&1; then
        pomp_args="$pomp_args --pypomp-python $python --replicates 2 --pypomp-batch 64"
    fi
    say "pomp_speed_session.py $pomp_args (at most $limit s) > $out/pomp.txt"
    started=$SECONDS
    # shellcheck disable=SC2086  # the arguments are words
    timeout "$limit" "$python" examples/benchmarks/pomp_speed_session.py $pomp_args >"$out/pomp.txt" 2>&1
    pomp_status=$?
    say "pomp models: exit $pomp_status after $((SECONDS - started)) s (rows finished: $(grep -c '^{' "$out/pomp.txt"))"
else
    say "pomp models: left out without a GPU (PFX_POMP_ARGS runs them anyway)"
fi
[ "$bench_status" -ne 0 ] && exit "$bench_status"
[ "$test_status" -ne 0 ] && exit "$test_status"
exit "$pomp_status"
