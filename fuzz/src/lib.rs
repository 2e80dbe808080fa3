//! The fuzz targets of posestream: every decoder of outside input, each a function of
//! the input bytes that must return (an error is fine) without panicking, aborting or
//! allocating beyond the service's limits.
//!
//! `fuzz_targets/*.rs` hand these to libFuzzer (`cargo fuzz`, see `fuzz/README.md`), and
//! `tests/fuzz_corpora.rs` in the main crate replays every committed corpus and crash
//! input through the same functions (this file is included there with `#[path]`), so CI
//! runs them without cargo-fuzz.

use posestream::LoadDictionary;
use std::io::Cursor;
use std::path::Path;
use std::sync::OnceLock;

use posestream::images::{decode_bytes, decode_compressed, decode_image};
use posestream::limits::Limits;
use posestream::mocap::{Bvh, SkeletonMapping, Split};
use posestream::msgs::{self, CompressedImage, HeatMaps, Image, Skeleton3D};
use posestream::nodes::markers::skeleton_markers;
use posestream::nodes::{EstimatorNode, ServiceConfig};
use posestream::recording::RecordingReader;
use posestream::transport::shm::{
    FRAME_ID_BYTES, HeatMapsHeader, MAX_JOINTS, NAME_BYTES, SampleText, SkeletonSample,
    heatmaps_from_sample, sample_view,
};
use posestream::{Dictionary, Estimator, Params, StreamSettings, WindowEstimator};

/// A fuzz target: its name (the folder of its corpus) and its function.
pub type Target = (&'static str, fn(&[u8]));

/// Every target.
pub const TARGETS: &[Target] = &[
    ("heatmaps_cdr", heatmaps_cdr),
    ("skeleton_cdr", skeleton_cdr),
    ("shm_sample", shm_sample),
    ("mcap", mcap),
    ("npy", npy),
    ("dictionary", dictionary),
    ("bvh", bvh),
    ("toml", toml),
    ("tflite", tflite),
    ("image_file", image_file),
    ("sensor_image", sensor_image),
    ("live_view", live_view),
];

/// Makes every panic fail the run (libFuzzer's hook aborts on any panic), except those
/// that posestream contains on purpose around a dependency's parser
/// ([`posestream::error::contain_panics`]): those are handled errors. Called by each
/// target; installs the hook once.
pub fn panics_abort_unless_contained() {
    static ONCE: OnceLock<()> = OnceLock::new();
    ONCE.get_or_init(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !posestream::error::panic_is_contained() {
                previous(info);
                std::process::abort();
            }
        }));
    });
}

/// A path that names the fuzz input in errors.
fn name(ext: &str) -> &'static Path {
    match ext {
        "npy" => Path::new("fuzz.npy"),
        "mat" => Path::new("fuzz.mat"),
        "json" => Path::new("fuzz.json"),
        "mcap" => Path::new("fuzz.mcap"),
        _ => Path::new("fuzz.toml"),
    }
}

/// The shipped dictionary, loaded once (the estimator node's).
fn dictionary_once() -> &'static Dictionary {
    static DICT: OnceLock<Dictionary> = OnceLock::new();
    DICT.get_or_init(|| {
        let here = Path::new(env!("CARGO_MANIFEST_DIR"));
        let relative = "config/dictionaries/default-k128.json";
        let path = [here.join(relative), here.join("..").join(relative)]
            .into_iter()
            .find(|p| p.is_file())
            .expect("the shipped dictionary");
        Dictionary::load(path).expect("the shipped dictionary loads")
    })
}

/// The estimator over the shipped dictionary, set up once (its SVDs and init cache
/// would otherwise dominate each run of the node's targets).
fn estimator_once() -> &'static Estimator {
    static ESTIMATOR: OnceLock<Estimator> = OnceLock::new();
    ESTIMATOR.get_or_init(|| {
        Estimator::new(dictionary_once().clone(), Params::default()).expect("estimator")
    })
}

/// A fresh estimator node (no state carried from one input to the next).
fn node() -> EstimatorNode {
    let estimator = estimator_once().clone();
    let window = WindowEstimator::new(estimator, StreamSettings::default()).expect("window");
    EstimatorNode::new(window)
}

/// A `posestream_msgs/HeatMaps` message from the network, through the estimator node
/// (decoding, limits, sizes, values, the window), twice (two frames of a track).
pub fn heatmaps_cdr(data: &[u8]) {
    let mut node = node();
    let mut out = Vec::new();
    let _ = node.handle_encoded(data, &mut out);
    if let Ok(mut m) = msgs::decode::<HeatMaps>(data) {
        m.sequence = m.sequence.wrapping_add(1);
        let _ = node.handle(&m, &mut out);
    }
    node.finish(&mut out);
    assert!(
        out.iter().all(Skeleton3D::is_finite),
        "a non-finite skeleton"
    );
    // The node catches panics to go on; here any one is a failure.
    assert_eq!(node.refused().of("panic"), 0, "a panic inside the node");
}

/// A `posestream_msgs/Skeleton3D` message: decoded, put into a shared-memory sample and
/// back, drawn as markers.
pub fn skeleton_cdr(data: &[u8]) {
    let Ok(m) = msgs::decode::<Skeleton3D>(data) else {
        return;
    };
    if let Ok(sample) = SkeletonSample::from_message(&m) {
        let _ = sample.to_message();
    }
    let p = m.joint_names.len();
    let bones: Vec<(usize, usize)> = (1..p.min(64)).map(|j| (j - 1, j)).collect();
    let _ = skeleton_markers(&m, &bones);
}

/// Little-endian fields out of the input, zeros past its end.
struct Fields<'a> {
    data: &'a [u8],
    at: usize,
}

impl Fields<'_> {
    fn bytes<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0_u8; N];
        for (i, o) in out.iter_mut().enumerate() {
            *o = self.data.get(self.at + i).copied().unwrap_or(0);
        }
        self.at += N;
        out
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.bytes())
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.bytes())
    }
    fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.bytes())
    }
    fn rest(&self) -> &[u8] {
        self.data.get(self.at..).unwrap_or_default()
    }
}

/// An iceoryx2 sample as a hostile publisher could lay it out in shared memory: the
/// first byte picks a heat-map header with its f32 payload, or a skeleton sample.
pub fn shm_sample(data: &[u8]) {
    let Some((&kind, data)) = data.split_first() else {
        return;
    };
    let mut f = Fields { data, at: 0 };
    if kind % 2 == 0 {
        let mut h = HeatMapsHeader {
            stamp_ns: f.u64() as i64,
            sequence: f.u64(),
            track_id: f.u32(),
            joints: f.u32(),
            height: f.u32(),
            width: f.u32(),
            crop: [f.f64(), f.f64(), f.f64(), f.f64()],
            ..HeatMapsHeader::default()
        };
        h.frame_id = f.bytes::<FRAME_ID_BYTES>();
        for name in h.joint_names.iter_mut().take(4) {
            *name = f.bytes::<NAME_BYTES>();
        }
        let payload: Vec<f32> = f
            .rest()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        let mut text = SampleText::default();
        let limits = Limits::default();
        if let Ok(view) = sample_view(&h, &payload, &limits, &mut text) {
            // The copy and the lent frame are the same frame, bit for bit (NaN too).
            let copy = heatmaps_from_sample(&h, &payload, &limits).expect("the same checks");
            assert_eq!(
                msgs::encode(&copy).ok(),
                msgs::encode(&view.to_message()).ok()
            );
            let mut node = node();
            let _ = node.handle_view(&view, &mut Vec::new());
            assert_eq!(node.refused().of("panic"), 0, "a panic inside the node");
        }
    } else {
        let mut s = SkeletonSample::from_message(&Skeleton3D::default()).expect("empty sample");
        s.stamp_ns = f.u64() as i64;
        s.sequence = f.u64();
        s.track_id = f.u32();
        s.joints = f.u32();
        s.lag = f.u32();
        [s.state, s.units] = f.bytes::<2>();
        s.frame_id = f.bytes::<FRAME_ID_BYTES>();
        for name in s.joint_names.iter_mut().take(4) {
            *name = f.bytes::<NAME_BYTES>();
        }
        for v in s.positions.iter_mut().take(3 * MAX_JOINTS) {
            *v = f.f64();
        }
        let _ = s.to_message();
    }
}

/// A recording: every message read, heat maps decoded, until the end or the first error
/// (strict); then again reading on past damage (`posestream_msgs::salvage`), which must
/// never fail nor skip more bytes than the file has.
pub fn mcap(data: &[u8]) {
    let Ok(reader) = RecordingReader::from_reader(Cursor::new(data), name("mcap").into(), 1 << 20)
    else {
        return;
    };
    let _ = reader.topics();
    for m in reader {
        let Ok(m) = m else { break };
        let _ = msgs::decode::<HeatMaps>(&m.data);
    }
    let Ok(reader) = RecordingReader::from_reader(Cursor::new(data), name("mcap").into(), 1 << 20)
    else {
        return;
    };
    let Ok(mut reader) = reader.salvaging() else {
        return;
    };
    for m in reader.by_ref() {
        let m = m.expect("reading on past damage never fails");
        let _ = msgs::decode::<HeatMaps>(&m.data);
    }
    let skipped = reader.skips().expect("salvaging");
    assert!(skipped.bytes <= data.len() as u64, "{skipped:?}");
}

/// What a live-view client sends the door (`transport::foxglove::wire`): after the first
/// byte (which says how the rest is cut into reads), a request head if one ends within
/// the limit (checked, and read as a server's answer too), then frames, read as a
/// viewer's and, from the same bytes, as the server's, until one is refused.
pub fn live_view(data: &[u8]) {
    use posestream::transport::foxglove::wire::{self, Frames, Seen};
    let Some((&first, rest)) = data.split_first() else {
        return;
    };
    let frames = match wire::head_end(rest) {
        Ok(Some(end)) => {
            let _ = wire::check_request(&rest[..end]);
            let _ = wire::upgraded(&rest[..end]);
            &rest[end..]
        }
        _ => rest,
    };
    let read = usize::from(first) * 7 + 1;
    for mut stream in [Frames::from_viewer(), Frames::from_server()] {
        let mut seen = Seen::default();
        for piece in frames.chunks(read) {
            if stream.scan(piece, &mut seen).is_err() {
                break;
            }
        }
    }
}

/// An NPY array, as f64 and as f32.
pub fn npy(data: &[u8]) {
    let _ = posestream::npy::from_bytes::<f64>(data, name("npy"));
    let _ = posestream::npy::from_bytes::<f32>(data, name("npy"));
}

/// A dictionary: the first byte picks MATLAB (`.mat`) or JSON; a loaded one must make an
/// estimator.
pub fn dictionary(data: &[u8]) {
    let Some((&kind, data)) = data.split_first() else {
        return;
    };
    let dict = if kind % 2 == 0 {
        posestream::dictionary::mat::from_bytes(data, name("mat"))
    } else {
        posestream::dictionary::json::from_bytes(data, name("json"))
    };
    if let Ok(d) = dict {
        let _ = Estimator::new(d, Params::default());
    }
}

/// A BVH motion-capture file: parsed, its first frames posed.
pub fn bvh(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    if let Ok(b) = Bvh::parse(&text) {
        for t in 0..b.frames().min(3) {
            let _ = b.positions(t);
        }
    }
}

/// A TOML file: the first byte picks the service configuration, a skeleton mapping, a
/// detector channel mapping or a train/test split.
pub fn toml(data: &[u8]) {
    let Some((&kind, data)) = data.split_first() else {
        return;
    };
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = name("toml");
    match kind % 4 {
        0 => {
            let _ = ServiceConfig::parse(text, path);
        }
        1 => {
            let _ = SkeletonMapping::parse(text, path);
        }
        2 => {
            let joints = &dictionary_once().skeleton().joints;
            let _ = posestream::detector::mapping::ChannelMapping::parse(text, path, joints);
        }
        _ => {
            let _ = posestream::msgs::toml_file::parse_toml::<Split>(text, path);
        }
    }
}

/// A model file (TFLite flatbuffer) through the rewrite that makes it runnable by tract.
pub fn tflite(data: &[u8]) {
    let _ = posestream::models::rewrite::rewrite_for_tract(data);
}

/// An image file (PNG, JPEG, GIF) as the folder source reads it.
pub fn image_file(data: &[u8]) {
    let _ = decode_bytes(data, &Limits::default());
}

/// A camera message: the first byte picks `sensor_msgs/Image` or `CompressedImage`.
pub fn sensor_image(data: &[u8]) {
    let Some((&kind, data)) = data.split_first() else {
        return;
    };
    let limits = Limits::default();
    if kind % 2 == 0 {
        if let Ok(m) = msgs::decode::<Image>(data) {
            let _ = decode_image(&m, &limits);
        }
    } else if let Ok(m) = msgs::decode::<CompressedImage>(data) {
        let _ = decode_compressed(&m, &limits);
    }
}
