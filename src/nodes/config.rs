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
use posestream_msgs::toml_file::{ConfigError, load_toml, parse_toml};

/// The whole configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct ServiceConfig {
    /// The detector node.
    pub detector: DetectorConfig,
    /// The estimator node.
    pub estimator: EstimatorConfig,
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
}

impl Default for DetectorConfig {
    fn default() -> Self {
        Self {
            source: DetectorSource::Recording,
            recording: PathBuf::from("builtin:recordings/byebye.mcap"),
            rate: ReplayRate::Recorded,
            repeat: 1,
            images: ImageSettings::default(),
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
    /// text) sets. Sections and keys in the order of the shipped file.
    pub fn annotated(&self, file: Option<(&Path, &toml::Table)>) -> Result<String, String> {
        let full = toml::to_string(self).map_err(|e| e.to_string())?;
        let origin = file.map(|(p, _)| p.display().to_string());
        let mut section: Vec<String> = Vec::new();
        let mut out = String::new();
        for line in full.lines().filter(|l| !l.trim().is_empty()) {
            if let Some(header) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
                section = header.split('.').map(str::to_string).collect();
                if !out.is_empty() {
                    out.push('\n');
                }
                out.push_str(line);
                out.push('\n');
                continue;
            }
            let Some((key, _)) = line.split_once(" = ") else {
                out.push_str(line);
                out.push('\n');
                continue;
            };
            let set_in_file = file.is_some_and(|(_, table)| {
                let mut t = table;
                for name in &section {
                    match t.get(name).and_then(toml::Value::as_table) {
                        Some(inner) => t = inner,
                        None => return false,
                    }
                }
                t.contains_key(key.trim().trim_matches('"'))
            });
            let from = match (&origin, set_in_file) {
                (Some(path), true) => path.as_str(),
                _ => "default",
            };
            out.push_str(&format!("{line:<40} # {from}\n"));
        }
        Ok(out)
    }

    /// Reads a configuration file and checks every value is in its domain.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ConfigError> {
        Self::checked(load_toml(path.as_ref())?, path.as_ref())
    }

    /// Parses configuration text (`path` names it in errors) and checks every value.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigError> {
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
        let e = &self.estimator;
        crate::error::check_range("max_tracks", e.max_tracks, 1, 64)
            .map_err(|x| x.within("estimator"))?;
        e.params.check().map_err(|x| x.within("estimator.params"))?;
        e.window.check().map_err(|x| x.within("estimator.window"))?;
        e.metric.check().map_err(|x| x.within("estimator.metric"))?;
        self.detector
            .images
            .check()
            .map_err(|x| x.within("detector.images"))?;
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
    pub metric: crate::metric::MetricSettings,
}

impl Default for EstimatorConfig {
    fn default() -> Self {
        Self {
            dictionary: PathBuf::from("builtin:dictionaries/default-k128.json"),
            params: Params::default(),
            window: StreamSettings::default(),
            input: Transport::Ros2,
            max_tracks: super::DEFAULT_MAX_TRACKS,
            metric: crate::metric::MetricSettings::default(),
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
    /// Transforms of each person's body and joint frames (`tf2_msgs/TFMessage`).
    pub tf: String,
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
}

impl Default for ReplayConfig {
    fn default() -> Self {
        Self {
            rate: ReplayRate::Fast,
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
mod tests {
    use super::*;

    /// `config/default.toml` lists every key with its default value.
    #[test]
    fn the_shipped_configuration_is_the_default_one_and_lists_every_key() {
        let text = include_str!("../../config/default.toml");
        let parsed: ServiceConfig = toml::from_str(text).expect("parses");
        assert_eq!(parsed, ServiceConfig::default());
        // Every key of the default, serialised, appears in the file.
        let full = toml::to_string(&ServiceConfig::default()).expect("serialises");
        let mut section = String::new();
        for line in full.lines() {
            if line.starts_with('[') {
                section = line.to_string();
                assert!(text.contains(line), "section {line} missing");
            } else if let Some((key, _)) = line.split_once(" = ") {
                let listed = text
                    .lines()
                    .any(|l| l.trim_start().starts_with(&format!("{key} = ")));
                // `init` is optional (None): listed commented out.
                assert!(listed || key == "init", "{section} {key} missing");
            }
        }
    }

    #[test]
    fn unknown_keys_and_bad_values_are_errors() {
        for bad in [
            "[ros.qos]\nreliabilty = \"reliable\"\n",
            "[ros.qos]\nreliability = \"sometimes\"\n",
            "[outputs]\nshm = true\n",
            "[iceoryx2]\nskeleton = \"x\"\n",
            "[detector]\nrate = \"slow\"\n",
            "[detector]\nsource = \"webcam\"\n",
            "[detector.images]\nmodel = \"huge\"\n",
            "[detector.images]\nperson = [1, 2, 3, 4]\n",
            "[estimator]\ninput = \"zenoh\"\n",
            "[estimator.params]\nstart_from_window = \"yes\"\n",
            "[estimator.params]\nstart_from_window = 1\n",
            "[estimator.params]\nstart_from_windows = false\n",
        ] {
            assert!(toml::from_str::<ServiceConfig>(bad).is_err(), "{bad}");
        }
    }
}
