# Sourced by scripts/test.sh and scripts/test-outside.sh: how both build climbsim, once and from
# scratch on a fresh machine, so that the second packs and installs the binary the first built
# instead of compiling it again (any difference in these settings is another build):
# - no incremental compilation: its bookkeeping is ~7 % more work when there is nothing to reuse;
# - climbsim's own crates in 16 code-generation units instead of the dev profile's 256: ~11 %
#   less work for the optimiser (the library: 162 against 144 CPU-s);
# - no line tables in climbsim and its test binaries (the dependencies have none already): the
#   library 9 % less work, 21 s less of a fresh clone's build on 2 cores (303 against 282 s,
#   `cargo test --no-run --timings`, 2026-11-28). A failed test still names its file and line
#   (a panic's location is compiled in); only a backtrace's frames lose theirs.
# `cargo test` run by hand keeps the dev profile (incremental, line tables); the two builds sit
# side by side in target/.
export CARGO_INCREMENTAL=0
fresh_build_config=(--config 'profile.dev.package.climbsim.codegen-units=16' --config 'profile.dev.debug=false')
