#!/bin/sh
# Fuzz the C core's frame logic (fuzz/TARGET.c, see their comments) with AFL++ for a bounded
# time: FUZZ_SECONDS (default 30, 6 under CI=true) a target, FUZZ_TARGETS (default all six)
# in turn, from the kept corpus fuzz/corpus/TARGET/ (seeded with valid frames by
# fuzz/seeds.py).  A crash (a rule the harness checks, or AddressSanitizer/UBSan) or a hang
# fails the run, and its input is printed in hex; replay one with
# build/fuzz/TARGET-replay < FILE.
#
# Compiler: afl-clang-fast (AFL++'s LLVM mode: Debian's afl++ brings clang; AddressSanitizer
# needs libclang-rt-14-dev), else afl-gcc-fast (the GCC plugin; Debian 12's refuses its own
# gcc, "GCC and plugin have incompatible versions", so there it is only a fallback for other
# systems); FUZZ_CC names another (e.g. afl-cc).  Each target is
# also built with plain cc and AddressSanitizer as TARGET-replay, and the corpus replayed
# first, so a regression in a kept input fails even before AFL++ starts.
# FUZZ_UPDATE_CORPUS=1: after the runs, the corpus becomes afl-cmin's minimum of the corpus
# and what AFL++ found (named by their SHA-1), plus the named seeds (commit fuzz/corpus/).
set -eu
cd "$(dirname "$0")/.."

# CI replays the whole kept corpus first anyway: a short run there only looks for new paths.
if [ "${CI:-}" = true ]; then default_seconds=6; else default_seconds=30; fi
seconds=${FUZZ_SECONDS:-$default_seconds}
targets=${FUZZ_TARGETS:-"rtu match request table stream take"}
out=${FUZZ_OUT:-build/fuzz}

sources() {
    case $1 in
        rtu) echo csrc/rtu.c ;;
        match) echo csrc/match.c csrc/mbap.c csrc/rtu.c csrc/crc.c ;;
        request) echo csrc/request.c csrc/rtu.c csrc/crc.c ;;
        table) echo csrc/table.c csrc/table_answer.c csrc/table_ident.c csrc/mbap.c ;;
        stream) echo csrc/match.c csrc/mbap.c csrc/rtu.c csrc/crc.c ;;
        take) echo csrc/mbap.c ;;
        *) echo "fuzz: unknown target $1 (rtu, match, request, table, stream, take)" >&2; exit 2 ;;
    esac
}

if [ -n "${FUZZ_CC:-}" ]; then
    cc_afl=$FUZZ_CC
elif command -v afl-clang-fast >/dev/null && command -v clang >/dev/null; then
    cc_afl=afl-clang-fast
elif command -v afl-gcc-fast >/dev/null; then
    cc_afl=afl-gcc-fast
else
    echo "fuzz: no AFL++ compiler (apt-get install afl++; scripts/setup.sh does)" >&2
    exit 1
fi

mkdir -p "$out"
flags="-std=gnu99 -g -O2 -Wall -Wextra -Werror -Icsrc -Ifuzz"
for target in $targets; do
    # shellcheck disable=SC2046,SC2086
    cc $flags -fsanitize=address,undefined -fno-sanitize-recover=all \
        -o "$out/$target-replay" "fuzz/$target.c" $(sources "$target") -lpthread
    for input in fuzz/corpus/"$target"/*; do
        "$out/$target-replay" < "$input" \
            || { echo "fuzz: $target: the kept input $input fails" >&2; exit 1; }
    done
    # shellcheck disable=SC2046,SC2086
    AFL_QUIET=1 AFL_USE_ASAN=1 AFL_USE_UBSAN=1 "$cc_afl" $flags \
        -o "$out/$target" "fuzz/$target.c" $(sources "$target") -lpthread
done

failed=0
for target in $targets; do
    findings="$out/$target-findings"
    rm -rf "$findings"
    echo "fuzz: $target for $seconds s ($cc_afl)"
    AFL_NO_UI=1 AFL_SKIP_CPUFREQ=1 AFL_NO_AFFINITY=1 AFL_FAST_CAL=1 \
        AFL_I_DONT_CARE_ABOUT_MISSING_CRASHES=1 AFL_SKIP_CRASHES=0 \
        afl-fuzz -i "fuzz/corpus/$target" -o "$findings" -V "$seconds" -t 1000 -m none \
        -- "$out/$target" > "$out/$target.log" 2>&1 \
        || { tail -20 "$out/$target.log" >&2; echo "fuzz: $target: afl-fuzz failed" >&2; exit 1; }
    stats="$findings/default/fuzzer_stats"
    echo "fuzz: $target: $(sed -n 's/^execs_done *: //p' "$stats") runs," \
         "$(sed -n 's/^corpus_count *: //p' "$stats") inputs in the queue"
    for kind in crashes hangs; do
        for found in "$findings/default/$kind"/id:*; do
            [ -e "$found" ] || continue
            failed=1
            echo "fuzz: $target: $kind: $found" >&2
            od -An -tx1 "$found" >&2
            "$out/$target-replay" < "$found" >&2 || true
        done
    done
    if [ "${FUZZ_UPDATE_CORPUS:-0}" = 1 ] && [ "$failed" = 0 ]; then
        rm -rf "$out/$target-min"
        mkdir -p "$out/$target-all"
        cp "fuzz/corpus/$target"/* "$findings/default/queue"/id:* "$out/$target-all/"
        AFL_QUIET=1 afl-cmin -i "$out/$target-all" -o "$out/$target-min" -- "$out/$target" \
            > /dev/null
        rm -rf "$out/$target-all" "fuzz/corpus/$target"
        mkdir "fuzz/corpus/$target"
        for kept in "$out/$target-min"/*; do       # AFL++'s names hold ':' and vary
            name=$(basename "$kept")
            case $name in id:*) name=$(sha1sum < "$kept" | cut -c1-16) ;; esac
            mv "$kept" "fuzz/corpus/$target/$name"
        done
        rm -rf "$out/$target-min"
    fi
done
if [ "${FUZZ_UPDATE_CORPUS:-0}" = 1 ]; then
    python3 fuzz/seeds.py                       # the named seeds stay whatever afl-cmin kept
fi
[ "$failed" = 0 ] || { echo "fuzz: crashes or hangs found (above)" >&2; exit 1; }
echo "fuzz: no crash, no hang"
