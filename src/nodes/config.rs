//! The service configuration (`config/default.toml`): every parameter of the estimator,
//! the window, the detector's replay source, topics, ROS 2 (domain, QoS), iceoryx2
//! services, outputs and replay. Unknown keys are errors.
//!
//! The defaults are built into the binary ([`ServiceConfig::default`], the same values
//! as the shipped file); a file given with `--config` overlays only the keys it sets
//! ([`ServiceConfig::load_or_default`]), and [`ServiceConfig::annotated`] writes the
//! effective configuration with where each value came from (`posestream config`).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::detector::ImageSettings;
use crate::error::OutOfDomain;
use crate::limits::Limits;
use crate::solver::Params;
use crate::streaming::StreamSettings;
use crate::transport::ros2::RosSettings;
use crate::transport::ros2::check_topic_name;
use crate::transport::shm::ShmSettings;
use posestream_msgs::toml_file::{ConfigError, parse_toml, read_toml};

/// Tracks an estimator node runs at once unless configured otherwise
/// (`[estimator] max_tracks`).
pub const DEFAULT_MAX_TRACKS: usize = 12;

/// The whole configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct ServiceConfig {
    /// The detector node.
    pub detector: DetectorConfig,
    /// The estimator node.
    pub estimator: EstimatorConfig,
    /// The fusion node: several cameras, one skeleton per person.
    pub fusion: FusionConfig,
    /// Topic names.
    pub topics: Topics,
    /// Where the nodes publish.
    pub outputs: OutputsConfig,
    /// ROS 2: domain, node, QoS.
    pub ros: RosSettings,
    /// iceoryx2 shared memory: service names.
    pub iceoryx2: ShmSettings,
    /// Replaying recordings.
    pub replay: ReplayConfig,
    /// The largest inputs accepted (maps, records, images).
    pub limits: Limits,
}

/// The detector node (`[detector]`): where heat maps come from: replayed from a
/// recording of heat maps (e.g. from `posestream synth --mcap`), or computed from camera
/// images by the image detector (`[detector.images]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DetectorConfig {
    /// Where the frames come from.
    pub source: DetectorSource,
    /// A recording (MCAP) with heat maps on `topics.heatmaps` (source `recording`).
    pub recording: PathBuf,
    /// `recorded`: at the recorded pace, as a camera would; `fast`: as fast as the
    /// readers take them (source `recording`; image sources run as fast as the model).
    pub rate: ReplayRate,
    /// Times the recording is played (source `recording`; 0: forever). Each pass starts
    /// a new track; log times go on.
    pub repeat: u64,
    /// The image detector (the other sources).
    pub images: ImageSettings,
    /// Where the estimator shares the process (`posestream run`), the image detector's
    /// threads (its own, LiteRT's, rayon's global pool) run at least this nice (0-19;
    /// Linux's nice values), the rest as started: a frame already detected gets its
    /// skeleton published before the next frame's detection takes the cores
    /// ([`crate::nodes::priority`]). 0: as started. Against other processes too: with
    /// no autogroup, they get more of the cores than the detector.
    pub nice: u8,
}

impl Default for DetectorConfig {
    fn default() -> Self {
        Self {
            source: DetectorSource::Recording,
            recording: PathBuf::from("builtin:recordings/byebye.mcap"),
            rate: ReplayRate::Recorded,
            repeat: 1,
            images: ImageSettings::default(),
            nice: 10,
        }
    }
}

/// Where the detector node's frames come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum DetectorSource {
    /// Heat maps replayed from `detector.recording`.
    Recording,
    /// The image files of the folder `detector.images.path`.
    Images,
    /// The video file `detector.images.path` (decoded by ffmpeg).
    Video,
    /// Camera images on `detector.images.topic` of the recording `detector.images.path`.
    ImageRecording,
    /// Camera images on the ROS 2 topic `detector.images.topic`.
    Ros2,
}

/// Where the estimator node (`posestream estimator`) reads heat maps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Transport {
    /// The ROS 2 topic `topics.heatmaps`.
    Ros2,
    /// The iceoryx2 service `iceoryx2.heatmaps`.
    Iceoryx2,
}

/// The type of REP-155's `/humans/bodies/<id>/roi` (`[outputs] hri_roi`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum HriRoi {
    /// `sensor_msgs/RegionOfInterest`, pixels (REP-155's text).
    Pixels,
    /// `hri_msgs/NormalizedRegionOfInterest2D`, fractions of the image (what ROS4HRI's
    /// libhri 2.x reads).
    Normalized,
}

/// `[outputs]`: where the nodes publish what they produce.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputsConfig {
    /// Publish on ROS 2 topics.
    pub ros2: bool,
    /// Publish on iceoryx2 services.
    pub iceoryx2: bool,
    /// Also publish skeletons as `visualization_msgs/MarkerArray` on `topics.markers`
    /// (ROS 2 and recordings).
    pub markers: bool,
    /// Also publish the skeletons of each image together as
    /// `posestream_msgs/Skeleton3DArray` on `topics.skeleton_arrays` (ROS 2 and
    /// recordings).
    pub arrays: bool,
    /// Also publish each person's body and joint frames on `topics.tf` (skeletons in
    /// metres only; ROS 2 and recordings).
    pub tf: bool,
    /// Also publish REP-155's (ROS4HRI) body topics under `topics.hri_bodies`: the ids
    /// tracked, and each body's region of interest and 2D skeleton (these two need the
    /// images' size, from the camera's calibration; ROS 2 and recordings).
    pub hri: bool,
    /// The type of REP-155's `<id>/roi`.
    pub hri_roi: HriRoi,
    /// Also record everything published to this MCAP file (empty: no recording).
    pub record: PathBuf,
    /// Also serve everything published to the Foxglove app, live (the Foxglove WebSocket
    /// protocol, read-only for its clients), on this address (`HOST:PORT`; empty: no).
    pub foxglove: String,
}

impl Default for OutputsConfig {
    fn default() -> Self {
        Self {
            ros2: true,
            iceoryx2: false,
            markers: true,
            arrays: true,
            tf: true,
            hri: true,
            hri_roi: HriRoi::Pixels,
            record: PathBuf::new(),
            foxglove: String::new(),
        }
    }
}

/// The environment variables that override configuration keys when a node starts (ROS 2's
/// conventions), with the key each overrides.
pub const ENVIRONMENT_OVERRIDES: &[(&str, &str)] = &[
    ("ROS_DOMAIN_ID", "ros.domain_id"),
    ("ROS_LOCALHOST_ONLY", "ros.localhost_only (when 1)"),
    (
        "ROS_AUTOMATIC_DISCOVERY_RANGE",
        "ros.localhost_only (when LOCALHOST)",
    ),
    ("ROS_SECURITY_ENABLE", "ros.security.enable (when true)"),
    ("ROS_SECURITY_KEYSTORE", "ros.security.keystore"),
    ("ROS_SECURITY_ENCLAVE_OVERRIDE", "ros.security.enclave"),
    (
        "POSESTREAM_LITERT",
        "detector.images.litert_library (when empty)",
    ),
    (
        "POSESTREAM_MODELS",
        "detector.images.models_dir (when empty)",
    ),
];

impl ServiceConfig {
    /// The built-in defaults overlaid with the keys `path` sets (`None`: the defaults),
    /// every value checked.
    pub fn load_or_default(path: Option<&Path>) -> Result<Self, ConfigError> {
        match path {
            Some(path) => Self::load(path),
            None => Ok(Self::default()),
        }
    }

    /// The configuration as TOML, every key with where its value came from: `# default`
    /// (built in), or `# FILE` for the keys `file` (the overlay's path and its parsed
    /// text) sets. Section by section, keys in the order of the configuration's types.
    pub fn annotated(&self, file: Option<(&Path, &toml::Table)>) -> Result<String, String> {
        let table = toml::Table::try_from(self).map_err(|e| e.to_string())?;
        let origin = file.map(|(p, _)| p.display().to_string());
        let mut out = String::new();
        annotate(
            &mut out,
            &[],
            &table,
            file.map(|(_, t)| t),
            origin.as_deref(),
        );
        Ok(out)
    }

    /// Reads a configuration file and checks every value is in its domain.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ConfigError> {
        let path = path.as_ref();
        Self::parse(&read_toml(path)?, path)
    }

    /// Parses configuration text (`path` names it in errors) and checks every value.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigError> {
        // The shape first, where the text is a TOML table (a value TOML's integers cannot
        // hold is left to the typed parse, which names it).
        if let Ok(table) = toml::from_str::<toml::Table>(text) {
            let defaults = toml::Table::try_from(Self::default()).unwrap_or_default();
            check_sections(&table, &defaults, "").map_err(|reason| ConfigError::Shape {
                path: path.to_path_buf(),
                reason,
            })?;
        }
        Self::checked(parse_toml(text, path)?, path)
    }

    fn checked(config: Self, path: &Path) -> Result<Self, ConfigError> {
        config.validate().map_err(|source| ConfigError::Domain {
            path: path.to_path_buf(),
            source,
        })?;
        Ok(config)
    }

    /// Checks every value is in its domain; the error names the key as the file spells
    /// it (`estimator.window.size must be in 1..=300, got 1000000000`).
    pub fn validate(&self) -> Result<(), OutOfDomain> {
        crate::error::check_range("repeat", self.detector.repeat, 0, 1_000_000)
            .map_err(|x| x.within("detector"))?;
        crate::error::check_range("nice", self.detector.nice, 0, 19)
            .map_err(|x| x.within("detector"))?;
        let e = &self.estimator;
        crate::error::check_range("max_tracks", e.max_tracks, 1, 64)
            .map_err(|x| x.within("estimator"))?;
        e.params.check().map_err(|x| x.within("estimator.params"))?;
        e.window.check().map_err(|x| x.within("estimator.window"))?;
        e.metric.check().map_err(|x| x.within("estimator.metric"))?;
        e.fusion.check().map_err(|x| x.within("estimator.fusion"))?;
        self.detector
            .images
            .check()
            .map_err(|x| x.within("detector.images"))?;
        self.fusion
            .check(&self.topics)
            .map_err(|x| x.within("fusion"))?;
        let t = &self.topics;
        let topics = [
            ("heatmaps", &t.heatmaps),
            ("skeletons", &t.skeletons),
            ("skeleton_arrays", &t.skeleton_arrays),
            ("markers", &t.markers),
            ("image_markers", &t.image_markers),
            ("ground_truth", &t.ground_truth),
            ("camera_info", &t.camera_info),
            ("tf", &t.tf),
            ("tf_static", &t.tf_static),
            ("floor", &t.floor),
        ];
        // The bodies' namespace: its topics are names of their own (`/humans/bodies/tracked`).
        check_topic_name("hri_bodies", &t.hri_bodies).map_err(|x| x.within("topics"))?;
        if let Some((other, _)) = topics.iter().find(|(_, topic)| {
            topic.starts_with(&format!("{}/", t.hri_bodies)) || **topic == t.hri_bodies
        }) {
            return Err(crate::error::OutOfDomain::new(
                "hri_bodies",
                format!("a namespace of its own (topics.{other} is in it, or is it)"),
                &t.hri_bodies,
            )
            .within("topics"));
        }
        for (i, (key, topic)) in topics.iter().enumerate() {
            check_topic_name(key, topic).map_err(|x| x.within("topics"))?;
            // Each carries its own type: two on one topic would mix them (a recording's
            // channel, a DDS topic).
            if let Some((other, _)) = topics[..i].iter().find(|(_, t)| t == topic) {
                return Err(crate::error::OutOfDomain::new(
                    key,
                    format!("a topic of its own, not topics.{other}'s"),
                    topic,
                )
                .within("topics"));
            }
        }
        if !self.outputs.foxglove.trim().is_empty() {
            socket_address(&self.outputs.foxglove).map_err(|domain| {
                crate::error::OutOfDomain::new(
                    "foxglove",
                    domain,
                    format!("{:?}", self.outputs.foxglove),
                )
                .within("outputs")
            })?;
        }
        self.ros.check().map_err(|x| x.within("ros"))?;
        self.iceoryx2.check().map_err(|x| x.within("iceoryx2"))?;
        self.limits.check().map_err(|x| x.within("limits"))?;
        Ok(())
    }
}

/// Writes `table`'s keys (section `path`) and then its sections into `out`, each key
/// with its origin: `origin` when `file` (the same section of the overlay) sets it.
fn annotate(
    out: &mut String,
    path: &[&str],
    table: &toml::Table,
    file: Option<&toml::Table>,
    origin: Option<&str>,
) {
    let leaves: Vec<_> = table.iter().filter(|(_, v)| !v.is_table()).collect();
    if !leaves.is_empty() && !path.is_empty() {
        if !out.is_empty() {
            out.push('\n');
        }
        out.push_str(&format!("[{}]\n", path.join(".")));
    }
    for (key, value) in leaves {
        let line = format!("{key} = {}", inline(value));
        let from = match (origin, file.is_some_and(|f| f.contains_key(key))) {
            (Some(o), true) => o,
            _ => "default",
        };
        out.push_str(&format!("{line:<40} # {from}\n"));
    }
    for (key, value) in table {
        if let Some(inner) = value.as_table() {
            let mut sub = path.to_vec();
            sub.push(key);
            let in_file = file
                .and_then(|f| f.get(key))
                .and_then(toml::Value::as_table);
            annotate(out, &sub, inner, in_file, origin);
        }
    }
}

/// A value on one line as TOML writes it: strings as basic strings with every control
/// character escaped (so no value spans lines), arrays and tables inline.
fn inline(value: &toml::Value) -> String {
    match value {
        toml::Value::String(s) => {
            let mut q = String::with_capacity(s.len() + 2);
            q.push('"');
            for c in s.chars() {
                match c {
                    '"' => q.push_str("\\\""),
                    '\\' => q.push_str("\\\\"),
                    '\n' => q.push_str("\\n"),
                    '\t' => q.push_str("\\t"),
                    '\r' => q.push_str("\\r"),
                    c if c.is_control() => q.push_str(&format!("\\u{:04X}", c as u32)),
                    c => q.push(c),
                }
            }
            q.push('"');
            q
        }
        toml::Value::Array(items) => {
            let items: Vec<String> = items.iter().map(inline).collect();
            format!("[{}]", items.join(", "))
        }
        toml::Value::Table(t) => {
            let items: Vec<String> = t
                .iter()
                .map(|(k, v)| {
                    format!(
                        "{} = {}",
                        inline(&toml::Value::String(k.clone())),
                        inline(v)
                    )
                })
                .collect();
            format!("{{ {} }}", items.join(", "))
        }
        other => other.to_string(),
    }
}

/// Checks that every section of the configuration that `text` (a file's, already parsed
/// as `table`) has is a table (`[detector]`), not an array of tables or a value: serde
/// would otherwise take an array for a struct's fields and say something unhelpful.
fn check_sections(table: &toml::Table, defaults: &toml::Table, path: &str) -> Result<(), String> {
    for (key, default) in defaults {
        let (Some(inner_default), Some(given)) = (default.as_table(), table.get(key)) else {
            continue;
        };
        let name = if path.is_empty() {
            key.clone()
        } else {
            format!("{path}.{key}")
        };
        match given.as_table() {
            Some(inner) => check_sections(inner, inner_default, &name)?,
            None => {
                let what = match given {
                    toml::Value::Array(_) => format!("an array (write [{name}], not [[{name}]])"),
                    _ => format!("a value ({})", given.type_str()),
                };
                return Err(format!("[{name}] must be a section (a table), not {what}"));
            }
        }
    }
    Ok(())
}

/// An address to serve on: `HOST:PORT` with an IP address or `localhost` (IPv6 in
/// brackets); the error says what is expected.
pub fn socket_address(text: &str) -> Result<std::net::SocketAddr, String> {
    let expected = || {
        "HOST:PORT with an IP address or localhost (127.0.0.1:8765, 0.0.0.0:8765, [::1]:8765)"
            .to_string()
    };
    let text = text.trim();
    if let Ok(address) = text.parse::<std::net::SocketAddr>() {
        return Ok(address);
    }
    match text.rsplit_once(':') {
        Some((host, port)) if host.eq_ignore_ascii_case("localhost") => port
            .parse::<u16>()
            .map(|p| std::net::SocketAddr::from(([127, 0, 0, 1], p)))
            .map_err(|_| expected()),
        _ => Err(expected()),
    }
}

/// The fusion node (`[fusion]`, `posestream fuse`): which cameras, where each is in the
/// world and how long a fused frame waits for them ([`crate::nodes::fusion`]); the
/// multi-view EM's own settings are `[estimator.fusion]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FusionConfig {
    /// The cameras' names: camera `c`'s heat maps come on `/<c><topics.heatmaps>` and its
    /// calibration on `/<c><topics.camera_info>`.
    pub cameras: Vec<String>,
    /// The frame the skeletons are in; with extrinsics from TF, each camera's frame (its
    /// heat maps' `frame_id`) must be in its tree.
    pub world_frame: String,
    /// Where the cameras' poses come from.
    pub extrinsics: ExtrinsicsSource,
    /// Each camera's pose in the world frame, `[x, y, z, qx, qy, qz, qw]` (metres and a
    /// unit quaternion of the camera's optical frame: x right, y down, z forward), by
    /// camera name (`extrinsics = "config"`).
    pub poses: std::collections::BTreeMap<String, Vec<f64>>,
    /// Each camera's intrinsics `[fx, fy, cx, cy]` (pixels), by camera name, in place of
    /// its `CameraInfo` (a camera not named here waits for its `CameraInfo`).
    pub intrinsics: std::collections::BTreeMap<String, Vec<f64>>,
    /// Fused frames per second: a camera's frame goes to the fused frame nearest its
    /// capture time (the fastest camera's rate).
    pub frame_rate: f64,
    /// Seconds a fused frame waits for the cameras still sending to send a later one;
    /// past it the frame is fused without them, and a camera silent this long is not
    /// waited for (measured in the input's clock: arrival time live, log time in a
    /// recording).
    pub wait: f64,
}

impl Default for FusionConfig {
    fn default() -> Self {
        Self {
            cameras: Vec::new(),
            world_frame: "world".into(),
            extrinsics: ExtrinsicsSource::Tf,
            poses: Default::default(),
            intrinsics: Default::default(),
            frame_rate: 30.0,
            wait: 0.2,
        }
    }
}

/// Where the fusion node's camera poses come from (`[fusion] extrinsics`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ExtrinsicsSource {
    /// `topics.tf_static` and `topics.tf`: `world_frame` to each camera's frame, as a
    /// robot publishes them.
    Tf,
    /// `[fusion.poses]`.
    Config,
}

/// The most cameras one fusion node takes.
pub const MAX_CAMERAS: usize = 16;

impl FusionConfig {
    /// Camera `name`'s heat-map and calibration topics.
    pub fn camera_topics(name: &str, topics: &Topics) -> (String, String) {
        (
            format!("/{name}{}", topics.heatmaps),
            format!("/{name}{}", topics.camera_info),
        )
    }

    /// Checks every value is in its domain.
    pub fn check(&self, topics: &Topics) -> Result<(), OutOfDomain> {
        if self.cameras.len() > MAX_CAMERAS {
            return Err(OutOfDomain::new(
                "cameras",
                format!("at most {MAX_CAMERAS} cameras"),
                self.cameras.len(),
            ));
        }
        for (i, name) in self.cameras.iter().enumerate() {
            let token = name
                .chars()
                .next()
                .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
                && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
            if !token {
                return Err(OutOfDomain::new(
                    "cameras",
                    "names of letters, digits and _, not starting with a digit (cam0)",
                    format!("{name:?}"),
                ));
            }
            if self.cameras[..i].contains(name) {
                return Err(OutOfDomain::new(
                    "cameras",
                    "names each given once",
                    format!("{name:?}"),
                ));
            }
            let (maps, info) = Self::camera_topics(name, topics);
            check_topic_name("cameras", &maps)?;
            check_topic_name("cameras", &info)?;
        }
        if !crate::floor::valid_frame_id(self.world_frame.trim_start_matches('/')) {
            return Err(OutOfDomain::new(
                "world_frame",
                "a frame id (letters, digits, _ and /)",
                format!("{:?}", self.world_frame),
            ));
        }
        for (key, table, len) in [
            ("poses", &self.poses, 7),
            ("intrinsics", &self.intrinsics, 4),
        ] {
            for (name, values) in table {
                let key = format!("{key}.{name}");
                if !self.cameras.contains(name) {
                    return Err(OutOfDomain::new(
                        &key,
                        "a camera of fusion.cameras",
                        format!("{name:?}"),
                    ));
                }
                if values.len() != len || !values.iter().all(|v| v.is_finite()) {
                    return Err(OutOfDomain::new(
                        &key,
                        format!("{len} finite numbers"),
                        format!("{values:?}"),
                    ));
                }
            }
        }
        for (name, q) in &self.poses {
            let norm = q[3..].iter().map(|v| v * v).sum::<f64>().sqrt();
            if !(0.99..=1.01).contains(&norm) {
                return Err(OutOfDomain::new(
                    &format!("poses.{name}"),
                    "a unit quaternion [qx, qy, qz, qw] after the position",
                    format!("{q:?} (norm {norm})"),
                ));
            }
        }
        for (name, k) in &self.intrinsics {
            if !k.iter().all(|v| *v > 0.0) {
                return Err(OutOfDomain::new(
                    &format!("intrinsics.{name}"),
                    "positive [fx, fy, cx, cy]",
                    format!("{k:?}"),
                ));
            }
        }
        if self.extrinsics == ExtrinsicsSource::Config
            && let Some(name) = self.cameras.iter().find(|c| !self.poses.contains_key(*c))
        {
            return Err(OutOfDomain::new(
                &format!("poses.{name}"),
                "a pose for every camera with extrinsics = \"config\"",
                "none",
            ));
        }
        crate::error::check_real("frame_rate", self.frame_rate, 0.1, 1000.0, false)?;
        crate::error::check_real("wait", self.wait, 0.0, 10.0, true)
    }
}

/// The estimator node (`[estimator]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EstimatorConfig {
    /// Pose dictionary (.json or the authors' .mat); relative to the working directory.
    pub dictionary: PathBuf,
    /// Solver weights and caps (`[estimator.params]`).
    pub params: Params,
    /// The sliding window (`[estimator.window]`).
    pub window: StreamSettings,
    /// Where `posestream estimator` reads heat maps.
    pub input: Transport,
    /// Tracks (people) estimated at once, each in a window of its own; a frame of one
    /// more is refused and counted.
    pub max_tracks: usize,
    /// Metres in the camera frame (`[estimator.metric]`), when the camera is known.
    pub metric: crate::metres::MetricSettings,
    /// Several cameras, one pose per person (`[estimator.fusion]`).
    pub fusion: crate::fusion::FusionSettings,
}

impl Default for EstimatorConfig {
    fn default() -> Self {
        Self {
            dictionary: PathBuf::from("builtin:dictionaries/default-k128.json"),
            params: Params::default(),
            window: StreamSettings::default(),
            input: Transport::Ros2,
            max_tracks: DEFAULT_MAX_TRACKS,
            metric: crate::metres::MetricSettings::default(),
            fusion: crate::fusion::FusionSettings::default(),
        }
    }
}

/// Topic names (`[topics]`), ROS 2 style.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Topics {
    /// Heat maps from the detector.
    pub heatmaps: String,
    /// Skeletons from the estimator.
    pub skeletons: String,
    /// The skeletons of each image together.
    pub skeleton_arrays: String,
    /// The skeletons as markers for RViz2 and Foxglove.
    pub markers: String,
    /// Each image's skeletons drawn over it (`visualization_msgs/ImageMarker`, image
    /// pixels), with `[outputs] markers`.
    pub image_markers: String,
    /// Ground-truth skeletons in synthetic recordings.
    pub ground_truth: String,
    /// The camera's calibration (`sensor_msgs/CameraInfo`) beside the heat maps: the
    /// estimator's metric step takes it (ROS 2 input, recordings).
    pub camera_info: String,
    /// Transforms of each person's body and joint frames (`tf2_msgs/TFMessage`); the
    /// estimator also reads the floor's frame from it (`[estimator.metric.floor]`).
    pub tf: String,
    /// Transforms valid at all times (`tf2_msgs/TFMessage`, latched): where the estimator
    /// reads a fixed camera's place over the floor (`[estimator.metric.floor] source = "tf"`).
    pub tf_static: String,
    /// The learnt floor with its uncertainty (`geometry_msgs/PoseWithCovarianceStamped`,
    /// latched: the camera's pose over `[estimator.metric.floor] published_frame`), each
    /// time a fit is trusted (`source = "learnt"`, with a `published_frame`).
    pub floor: String,
    /// The namespace of REP-155's bodies: `<this>/tracked` lists the ids, and
    /// `<this>/<id>/roi` and `<this>/<id>/skeleton2d` describe each.
    pub hri_bodies: String,
}

impl Default for Topics {
    fn default() -> Self {
        Self {
            heatmaps: "/posestream/heatmaps".into(),
            skeletons: "/posestream/skeletons".into(),
            skeleton_arrays: "/posestream/skeleton_arrays".into(),
            markers: "/posestream/markers".into(),
            image_markers: "/posestream/image_markers".into(),
            ground_truth: "/posestream/ground_truth".into(),
            camera_info: "/camera/camera_info".into(),
            tf: "/tf".into(),
            tf_static: "/tf_static".into(),
            floor: "/posestream/floor".into(),
            hri_bodies: "/humans/bodies".into(),
        }
    }
}

/// How recordings are replayed (`[replay]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReplayConfig {
    /// `fast`: as fast as possible; `recorded`: at the recorded pace.
    pub rate: ReplayRate,
    /// Stop reading a recording at its first damaged part, with an error (false: skip
    /// what cannot be read, use everything else, and say what was skipped). Every
    /// command reading a recording (`replay`, `detector`/`run --recording`, an
    /// `image-recording` source, `render`); `--strict` sets it.
    pub strict: bool,
}

impl Default for ReplayConfig {
    fn default() -> Self {
        Self {
            rate: ReplayRate::Fast,
            strict: false,
        }
    }
}

impl ReplayConfig {
    /// A recording source as configured: reading on past damage unless strict.
    pub fn source<M: crate::transport::Message>(
        &self,
        source: crate::transport::mcap::McapSource<M>,
    ) -> Result<crate::transport::mcap::McapSource<M>, crate::transport::TransportError> {
        if self.strict {
            Ok(source)
        } else {
            source.salvaging()
        }
    }
}

/// Replay pace.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum ReplayRate {
    /// As fast as possible.
    Fast,
    /// At the recorded pace (log times).
    Recorded,
}

#[cfg(test)]
mod tests;
