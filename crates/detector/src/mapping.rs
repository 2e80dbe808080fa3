//! From a detector's heat-map channels to the dictionary's joints
//! (`config/detectors/*.toml`): each joint is one channel, the pixel-wise mean of
//! several channels' scores, or unobserved (an all-zero map, which the E-step reads as
//! "no observation").

use std::collections::BTreeMap;
use std::path::Path;

use serde::Deserialize;

use posestream_msgs::toml_file::{ConfigError, load_toml};

/// Where a dictionary joint's heat map comes from among the detector's channels: one
/// channel, the pixel-wise mean of several, or none.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(untagged)]
pub enum ChannelSource {
    /// One channel.
    Channel(SingleChannel),
    /// The pixel-wise mean of several channels.
    Mean(MeanSource),
    /// No channel: an all-zero map.
    Unobserved(Unobserved),
}

/// `{ channel = c }`: a joint's map is one channel's.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SingleChannel {
    /// The channel.
    pub channel: usize,
}

/// `{ mean = [a, b, ...] }`.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeanSource {
    /// The channels averaged.
    pub mean: Vec<usize>,
}

/// `"unobserved"`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Unobserved {
    /// The joint has no channel.
    Unobserved,
}

/// The file: the detector's channel count and a source per joint.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MappingFile {
    /// Channels the detector emits.
    pub channels: usize,
    /// Joint name to source.
    pub joints: BTreeMap<String, ChannelSource>,
}

/// Why a mapping is unusable.
#[derive(Debug, thiserror::Error)]
pub enum ChannelMappingError {
    /// The file could not be read or parsed.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// A joint of the dictionary has no entry.
    #[error("joint `{0}` of the dictionary is not in the mapping")]
    MissingJoint(String),
    /// An entry names a joint the dictionary does not have.
    #[error("joint `{0}` is not a joint of the dictionary")]
    UnknownJoint(String),
    /// A channel is out of range, or a mean is empty.
    #[error("joint `{joint}`: {reason}")]
    Channel {
        /// The joint.
        joint: String,
        /// What is wrong.
        reason: String,
    },
    /// The maps given do not have the mapping's channel count or size.
    #[error("{0}")]
    Shape(String),
}

/// A mapping checked against the dictionary's joints, in their order.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelMapping {
    channels: usize,
    sources: Vec<Vec<usize>>,
}

impl ChannelMapping {
    /// Reads `path` and checks it against `joints` (the dictionary's, in order).
    pub fn load(path: impl AsRef<Path>, joints: &[String]) -> Result<Self, ChannelMappingError> {
        let file: MappingFile = load_toml(path.as_ref())?;
        Self::new(&file, joints)
    }

    /// Parses mapping text (`path` names it in errors) and checks it against `joints`.
    pub fn parse(text: &str, path: &Path, joints: &[String]) -> Result<Self, ChannelMappingError> {
        let file: MappingFile = posestream_msgs::toml_file::parse_toml(text, path)?;
        Self::new(&file, joints)
    }

    /// Checks `file` against `joints`.
    pub fn new(file: &MappingFile, joints: &[String]) -> Result<Self, ChannelMappingError> {
        if let Some(unknown) = file.joints.keys().find(|k| !joints.contains(k)) {
            return Err(ChannelMappingError::UnknownJoint(unknown.clone()));
        }
        let mut sources = Vec::with_capacity(joints.len());
        for joint in joints {
            let source = file
                .joints
                .get(joint)
                .ok_or_else(|| ChannelMappingError::MissingJoint(joint.clone()))?;
            let channels = match source {
                ChannelSource::Channel(c) => vec![c.channel],
                ChannelSource::Mean(m) if m.mean.is_empty() => {
                    return Err(ChannelMappingError::Channel {
                        joint: joint.clone(),
                        reason: "a mean of no channels (write \"unobserved\")".into(),
                    });
                }
                ChannelSource::Mean(m) => m.mean.clone(),
                ChannelSource::Unobserved(_) => Vec::new(),
            };
            if let Some(c) = channels.iter().find(|&&c| c >= file.channels) {
                return Err(ChannelMappingError::Channel {
                    joint: joint.clone(),
                    reason: format!("channel {c} of a detector with {}", file.channels),
                });
            }
            sources.push(channels);
        }
        Ok(Self {
            channels: file.channels,
            sources,
        })
    }

    /// Joints (maps written by [`Self::apply`]).
    pub fn joints(&self) -> usize {
        self.sources.len()
    }

    /// Joints with no channel.
    pub fn unobserved(&self) -> usize {
        self.sources.iter().filter(|s| s.is_empty()).count()
    }

    /// Turns the detector's logits (`height x width x channels`, channel fastest, as
    /// BlazePose emits them) into the joints' maps (`joints x height x width`,
    /// joint-major): scores by the logistic function, combined as the mapping says.
    pub fn apply(
        &self,
        logits: &[f32],
        height: usize,
        width: usize,
        out: &mut Vec<f32>,
    ) -> Result<(), ChannelMappingError> {
        let cells = height * width;
        if logits.len() != cells * self.channels || cells == 0 {
            return Err(ChannelMappingError::Shape(format!(
                "{} logits for {height} x {width} x {} channels",
                logits.len(),
                self.channels
            )));
        }
        out.clear();
        out.resize(self.sources.len() * cells, 0.0);
        for (map, channels) in out.chunks_exact_mut(cells).zip(&self.sources) {
            if channels.is_empty() {
                continue;
            }
            let weight = 1.0 / channels.len() as f32;
            for (cell, value) in map.iter_mut().enumerate() {
                let at = cell * self.channels;
                *value = channels
                    .iter()
                    .map(|&c| sigmoid(logits[at + c]))
                    .sum::<f32>()
                    * weight;
            }
        }
        Ok(())
    }
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn joints() -> Vec<String> {
        ["pelvis", "l-hip", "r-hip", "head-top"]
            .map(String::from)
            .to_vec()
    }

    fn file(text: &str) -> Result<MappingFile, toml::de::Error> {
        toml::from_str(text)
    }

    #[test]
    fn channels_means_and_unobserved_joints_become_maps() {
        let f = file(
            "channels = 3\n[joints]\npelvis = { mean = [0, 1] }\nl-hip = { channel = 0 }\n\
             r-hip = { channel = 1 }\nhead-top = \"unobserved\"\n",
        )
        .expect("parses");
        let m = ChannelMapping::new(&f, &joints()).expect("valid");
        assert_eq!((m.joints(), m.unobserved()), (4, 1));
        // 1 x 2 cells, 3 channels.
        let logits = [0.0, 2.0, 9.0, -1.0, 0.5, 9.0];
        let mut out = Vec::new();
        m.apply(&logits, 1, 2, &mut out).expect("applies");
        let s = sigmoid;
        let want = [
            (s(0.0) + s(2.0)) / 2.0,
            (s(-1.0) + s(0.5)) / 2.0,
            s(0.0),
            s(-1.0),
            s(2.0),
            s(0.5),
            0.0,
            0.0,
        ];
        for (a, b) in out.iter().zip(want) {
            assert!((a - b).abs() < 1e-6, "{out:?}");
        }
        assert!(m.apply(&logits[..5], 1, 2, &mut out).is_err());
    }

    #[test]
    fn bad_mappings_are_errors() {
        let base = "channels = 3\n[joints]\nl-hip = { channel = 0 }\nr-hip = { channel = 1 }\n\
                    head-top = \"unobserved\"\n";
        let check = |extra: &str| {
            let f = file(&format!("{base}{extra}"))?;
            Ok::<_, toml::de::Error>(ChannelMapping::new(&f, &joints()))
        };
        assert!(matches!(
            check(""),
            Ok(Err(ChannelMappingError::MissingJoint(_)))
        ));
        assert!(matches!(
            check("pelvis = { channel = 3 }\n"),
            Ok(Err(ChannelMappingError::Channel { .. }))
        ));
        assert!(matches!(
            check("pelvis = { mean = [] }\n"),
            Ok(Err(ChannelMappingError::Channel { .. }))
        ));
        assert!(matches!(
            check("pelvis = { channel = 0 }\nnose = { channel = 2 }\n"),
            Ok(Err(ChannelMappingError::UnknownJoint(_)))
        ));
        assert!(check("pelvis = \"missing\"\n").is_err(), "not a source");
        assert!(check("pelvis = { channel = 0, weight = 2 }\n").is_err());
    }

    #[test]
    fn the_shipped_blazepose_mapping_fits_the_shipped_dictionary() {
        // The workspace root, two folders above this crate.
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let dict = <posestream_math::Dictionary as posestream_msgs::formats::LoadDictionary>::load(
            root.join("config/dictionaries/default-k128.json"),
        )
        .expect("dictionary");
        let m = ChannelMapping::load(
            root.join("config/detectors/blazepose.toml"),
            &dict.skeleton().joints,
        )
        .expect("valid");
        assert_eq!((m.joints(), m.unobserved()), (17, 2));
    }
}
