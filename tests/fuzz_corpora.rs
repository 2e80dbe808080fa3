//! Every fuzz target (`fuzz/src/lib.rs`, included here) over its committed corpus
//! (`fuzz/corpus/<target>/`) and over every input that once made it fail
//! (`fuzz/regressions/<target>/`): CI replays them all without cargo-fuzz.

mod common;

#[allow(
    dead_code,
    missing_docs,
    reason = "the fuzz crate's helpers, of which this test uses some"
)]
#[path = "../fuzz/src/lib.rs"]
mod targets;

#[test]
fn every_fuzz_corpus_and_regression_input_replays_without_a_failure() {
    for (name, target) in targets::TARGETS {
        let mut inputs = 0;
        for dir in ["corpus", "regressions"] {
            let folder = common::root().join("fuzz").join(dir).join(name);
            let Ok(entries) = std::fs::read_dir(&folder) else {
                continue;
            };
            for entry in entries {
                let path = entry.expect("entry").path();
                let data = std::fs::read(&path).expect("read");
                let outcome = std::panic::catch_unwind(|| target(&data));
                assert!(outcome.is_ok(), "{name} fails on {}", path.display());
                inputs += 1;
            }
        }
        assert!(inputs > 0, "{name}: no corpus");
    }
}
