#!/usr/bin/env bash
# Mutation testing of the modules that carry the rules README states (issue 44): every rule
# should have a test that fails when the rule is changed. Not part of CI: each mutant is a
# rebuild plus a test run (about a minute each on 2 cores with the default test subset).
#
#   scripts/mutants.sh                  # the scoped modules below
#   scripts/mutants.sh src/io/atomic.rs # one file (repeat for more)
#   MUTANTS_TESTS="--lib --test suite tests:: cli::" scripts/mutants.sh ...   # another test subset
#                                       # (the integration tests are one binary, `suite`, a module
#                                       # per file of tests/: `cli::` picks tests/cli.rs and every
#                                       # *_cli.rs; name filters apply to --lib's tests too, whose
#                                       # names hold `tests::`)
#   scripts/mutants.sh --list           # list the mutants only
#   MUTANTS_IN_PLACE=1 scripts/mutants.sh ...  # mutate this tree (a spare worktree) and reuse
#                                       # its target/ instead of a cold build in a copy
#   MUTANTS_RE='in (boost|solve_radiance)$' scripts/mutants.sh ...  # only the mutants whose
#                                       # name matches (cargo-mutants --re: a file's rules by function)
#   MUTANTS_TESTS="--lib light_recovery" ...   # test-name filters after the targets (any number)
#   MUTANTS_PROFILE=release scripts/mutants.sh ...  # another cargo profile (default: `mutants`,
#                                       # Cargo.toml: opt-level 1, incremental)
#
# Builds use the `mutants` profile (Cargo.toml): incremental at opt-level 1, a mutant's rebuild
# takes ~10-40 s instead of release's ~175 s on this 2-core machine (measured 2026-11-27).
#
# cargo-mutants (crates.io) is installed into .tools/ on first use. Results go to
# target/mutants/mutants.out/ (missed.txt lists the survivors); docs/mutants.md keeps the
# latest survivor list with a word on each.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
version=27.1.0
if ! .tools/bin/cargo-mutants mutants --version 2>/dev/null | grep -q "$version"; then
    cargo install cargo-mutants --locked --version "$version" --root .tools
fi
./scripts/setup-test-env.sh
# The copy cargo-mutants builds in has no ../shared beside it.
export DRBOKEH_SHARED=${DRBOKEH_SHARED:-$(cd "$root/../shared" && pwd)}
list=()
files=()
[ -n "${MUTANTS_IN_PLACE:-}" ] && list+=(--in-place)
[ -n "${MUTANTS_RE:-}" ] && list+=(--re "$MUTANTS_RE")
for a in "$@"; do
    case "$a" in
        --list) list+=(--list) ;;
        *) files+=(--file "$a") ;;
    esac
done
if [ ${#files[@]} -eq 0 ]; then
    for f in src/stages/highlight_completion.rs src/stages/fill_depth.rs src/stages/contamination.rs \
        src/stages/highlights.rs src/stages/light_recovery.rs src/stages/background.rs src/render/lens.rs src/render/composite.rs \
        src/diff/loss.rs src/batch/mod.rs src/batch/schedule.rs src/io/atomic.rs src/io/guard.rs src/io/dynamic_depth.rs src/io/xmp.rs \
        src/focus_pull.rs src/view.rs src/diff/dfd_confidence.rs src/io/heif.rs src/io/heif_depth.rs; do
        files+=(--file "$f")
    done
fi
# The fast tests that exercise these modules; the full suite per mutant would take hours.
# `tests::` keeps every unit test of --lib (their modules are `tests`); the rest pick files of
# the integration suite.
read -r -a tests <<< "${MUTANTS_TESTS:---lib --test suite tests:: cli:: batch:: invariants:: stability:: backward::}"
# Target selectors (--lib, --test NAME, ...) go to the build as well as to the test run
# (`--cargo-arg`): without them each mutant's build compiled every test binary and example
# (~40 targets, 2-4 minutes at nice 19) to run four. Test-name filters go to the run only.
targets=()
filters=()
for ((i = 0; i < ${#tests[@]}; i++)); do
    case "${tests[$i]}" in
        --lib | --bins | --tests | --examples | --benches | --all-targets) targets+=(--cargo-arg="${tests[$i]}") ;;
        --test | --bin | --example | --bench)
            targets+=(--cargo-arg="${tests[$i]}=${tests[$((i + 1))]}")
            i=$((i + 1))
            ;;
        *) filters+=(--cargo-test-arg="${tests[$i]}") ;;
    esac
done
# Test-name filters go after `--`: cargo test takes one before it, the test harness any number
# (`MUTANTS_TESTS="--lib --test suite embedded_depth::dynamic embedded_depth::damaged"`).
[ ${#filters[@]} -gt 0 ] && filters=(--cargo-test-arg=-- "${filters[@]}")
# A fresh worktree has no target/ yet; cargo-mutants wants the output's parent to exist.
mkdir -p target
exec .tools/bin/cargo-mutants mutants "${list[@]}" "${files[@]}" --output target/mutants --timeout-multiplier 3 --minimum-test-timeout 120 \
    --cargo-arg=--profile="${MUTANTS_PROFILE:-mutants}" "${targets[@]}" "${filters[@]}"
