#!/usr/bin/env bash
# Run the default test suite (the README's test command) under BLAS kernels and NumPy SIMD
# settings of other CPUs, as a developer does before a release: results must not hang on the
# last bits of floating point (FMA, vector width and summation order differ between CPUs).
#
#   tools/portable_suite.sh            # every setting this CPU can run, one after the other
#   tools/portable_suite.sh Haswell    # one OpenBLAS kernel (with NumPy's AVX-512 switched off)
#
# Each setting is one full run of `python -m pytest` (about 10-20 minutes on 2 cores); extra
# pytest arguments go after `--`: tools/portable_suite.sh Haswell -- tests/simulation
set -uo pipefail
cd "$(dirname "$0")/.."

flags="$(grep -m1 '^flags' /proc/cpuinfo 2>/dev/null || true)"
kernels=()
for k in "$@"; do
  [ "$k" = "--" ] && break
  kernels+=("$k")
done
if [ "${#kernels[@]}" -eq 0 ]; then
  kernels=(Prescott)
  case "$flags" in *" avx2 "*) kernels+=(Haswell Zen) ;; esac
  case "$flags" in *" avx512f "*) kernels+=(SkylakeX) ;; esac
fi
extra=()
seen=0
for a in "$@"; do
  if [ "$seen" -eq 1 ]; then extra+=("$a"); fi
  [ "$a" = "--" ] && seen=1
done

# NumPy's dispatch: without AVX-512 (what an AVX2-only CPU runs) and, for the oldest kernel,
# without AVX2 and FMA too (baseline SSE)
no_avx512="AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR"
status=0
for k in "${kernels[@]}"; do
  features="$no_avx512"
  [ "$k" = "Prescott" ] && features="$no_avx512 AVX2 FMA3 AVX F16C"
  [ "$k" = "SkylakeX" ] && features=""
  echo "== OPENBLAS_CORETYPE=$k NPY_DISABLE_CPU_FEATURES='$features'"
  OPENBLAS_CORETYPE="$k" NPY_DISABLE_CPU_FEATURES="$features" python -m pytest -q "${extra[@]}" || status=1
done
exit "$status"
