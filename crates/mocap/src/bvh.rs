//! A BVH (Biovision Hierarchy) reader with forward kinematics.
//!
//! Supports any hierarchy (several `ROOT`s too), any channel order per joint, position
//! channels on any joint and `End Site`s. Conventions, as in the common readers:
//! - a joint's local transform is `translate(t) * R(c1) * R(c2) * R(c3)`, the rotation
//!   channels applied in the order they are listed (degrees);
//! - `t` is the joint's `OFFSET`, except that each position channel replaces its axis of
//!   the offset (a joint with `Xposition Yposition Zposition` ignores its offset);
//! - an `End Site` becomes a joint named `<parent>_end` with no channels.
//!
//! No maintained crate parses all of this (position channels on inner joints in
//! particular), so the parser is the project's own.

use std::path::Path;

use nalgebra::{Matrix3, Rotation3, Vector3};

use crate::error::BvhError;

/// One channel of a joint.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Channel {
    /// Translation along x.
    Xposition,
    /// Translation along y.
    Yposition,
    /// Translation along z.
    Zposition,
    /// Rotation about x, degrees.
    Xrotation,
    /// Rotation about y, degrees.
    Yrotation,
    /// Rotation about z, degrees.
    Zrotation,
}

impl Channel {
    fn parse(s: &str) -> Option<Self> {
        Some(match s.to_ascii_lowercase().as_str() {
            "xposition" => Self::Xposition,
            "yposition" => Self::Yposition,
            "zposition" => Self::Zposition,
            "xrotation" => Self::Xrotation,
            "yrotation" => Self::Yrotation,
            "zrotation" => Self::Zrotation,
            _ => return None,
        })
    }
}

/// A joint (or End Site) of the hierarchy.
#[derive(Debug, Clone, PartialEq)]
pub struct BvhJoint {
    /// Name; End Sites are `<parent>_end`.
    pub name: String,
    /// Parent joint, `None` for a root.
    pub parent: Option<usize>,
    /// `OFFSET` from the parent, file units.
    pub offset: [f64; 3],
    /// Channels in file order.
    pub channels: Vec<Channel>,
    /// Index of the first channel in a motion row.
    pub first_channel: usize,
    /// True for an `End Site`.
    pub end_site: bool,
}

/// A parsed BVH file: the hierarchy and the motion rows.
#[derive(Debug, Clone, PartialEq)]
pub struct Bvh {
    /// Joints, parents before children (file order).
    pub joints: Vec<BvhJoint>,
    /// Seconds per frame.
    pub frame_time: f64,
    /// Channel values, `frames` rows of `channels` values.
    pub motion: Vec<f64>,
    /// Channels per frame.
    pub channels: usize,
}

/// A whitespace-separated token with its 1-based line.
struct Tokens<'a> {
    items: Vec<(usize, &'a str)>,
    pos: usize,
}

impl<'a> Tokens<'a> {
    fn new(text: &'a str) -> Self {
        let items = text
            .lines()
            .enumerate()
            .flat_map(|(i, l)| l.split_whitespace().map(move |t| (i + 1, t)))
            .collect();
        Self { items, pos: 0 }
    }

    fn line(&self) -> usize {
        self.items
            .get(self.pos.min(self.items.len().saturating_sub(1)))
            .map_or(0, |t| t.0)
    }

    fn next(&mut self, expected: &str) -> Result<(usize, &'a str), BvhError> {
        let t = self
            .items
            .get(self.pos)
            .copied()
            .ok_or_else(|| BvhError::Syntax {
                line: self.line(),
                detail: format!("file ends where {expected} was expected"),
            })?;
        self.pos += 1;
        Ok(t)
    }

    fn peek(&self) -> Option<&'a str> {
        self.items.get(self.pos).map(|t| t.1)
    }

    fn expect(&mut self, word: &str) -> Result<(), BvhError> {
        let (line, t) = self.next(&format!("`{word}`"))?;
        if t.eq_ignore_ascii_case(word) {
            Ok(())
        } else {
            Err(BvhError::Syntax {
                line,
                detail: format!("expected `{word}`, found `{t}`"),
            })
        }
    }

    fn number(&mut self, what: &str) -> Result<f64, BvhError> {
        let (line, t) = self.next(what)?;
        let v: f64 = t.parse().map_err(|_| BvhError::Syntax {
            line,
            detail: format!("expected {what}, found `{t}`"),
        })?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(BvhError::Syntax {
                line,
                detail: format!("{what} is not finite: `{t}`"),
            })
        }
    }
}

/// The largest BVH file read (a take of 10 minutes at 120 frames/s of 60 joints is about
/// 40 MB).
pub const MAX_BVH_BYTES: u64 = 128 << 20;

impl Bvh {
    /// Reads and parses a BVH file (a regular file of at most [`MAX_BVH_BYTES`]).
    pub fn load(path: impl AsRef<Path>) -> Result<Self, BvhError> {
        let path = path.as_ref();
        let text =
            posestream_base::files::read_capped_string(path, MAX_BVH_BYTES).map_err(|source| {
                BvhError::Io {
                    path: path.to_path_buf(),
                    source,
                }
            })?;
        Self::parse(&text).map_err(|e| e.in_file(path))
    }

    /// Parses BVH text.
    pub fn parse(text: &str) -> Result<Self, BvhError> {
        let mut tok = Tokens::new(text);
        tok.expect("HIERARCHY")?;
        let mut joints: Vec<BvhJoint> = Vec::new();
        let mut channels = 0;
        loop {
            match tok.peek() {
                Some(t) if t.eq_ignore_ascii_case("ROOT") => {
                    tok.pos += 1;
                    parse_joint(&mut tok, None, false, &mut joints, &mut channels)?;
                }
                Some(t) if t.eq_ignore_ascii_case("MOTION") => break,
                Some(t) => {
                    return Err(BvhError::Syntax {
                        line: tok.line(),
                        detail: format!("expected `ROOT` or `MOTION`, found `{t}`"),
                    });
                }
                None => {
                    return Err(BvhError::Syntax {
                        line: tok.line(),
                        detail: "file ends before `MOTION`".into(),
                    });
                }
            }
        }
        if joints.is_empty() {
            return Err(BvhError::Syntax {
                line: tok.line(),
                detail: "the hierarchy has no ROOT joint".into(),
            });
        }
        tok.expect("MOTION")?;
        tok.expect("Frames:")?;
        let declared = tok.number("the frame count")?;
        if declared < 0.0 || declared.fract() != 0.0 {
            return Err(BvhError::Syntax {
                line: tok.line(),
                detail: format!("frame count {declared} is not a whole number"),
            });
        }
        let frames = declared as usize;
        tok.expect("Frame")?;
        tok.expect("Time:")?;
        let frame_time = tok.number("the frame time")?;
        if frame_time <= 0.0 {
            return Err(BvhError::Syntax {
                line: tok.line(),
                detail: format!("frame time {frame_time} is not positive"),
            });
        }
        let values = &tok.items[tok.pos..];
        if frames.checked_mul(channels) != Some(values.len()) {
            return Err(BvhError::MotionSize {
                declared: frames,
                channels,
                values: values.len(),
            });
        }
        let mut motion = Vec::with_capacity(values.len());
        for &(line, t) in values {
            match t.parse::<f64>() {
                Ok(v) if v.is_finite() => motion.push(v),
                _ => {
                    return Err(BvhError::Syntax {
                        line,
                        detail: format!("motion value `{t}` is not a finite number"),
                    });
                }
            }
        }
        Ok(Self {
            joints,
            frame_time,
            motion,
            channels,
        })
    }

    /// Number of frames.
    pub fn frames(&self) -> usize {
        self.motion.len().checked_div(self.channels).unwrap_or(0)
    }

    /// Index of the joint called `name`.
    pub fn index_of(&self, name: &str) -> Option<usize> {
        self.joints.iter().position(|j| j.name == name)
    }

    /// Global positions of every joint in frame `t` (file units, file axes), written into
    /// `out` (one `[x, y, z]` per joint).
    pub fn positions_into(&self, t: usize, out: &mut Vec<Vector3<f64>>) {
        let row = &self.motion[t * self.channels..(t + 1) * self.channels];
        let mut rotations: Vec<Matrix3<f64>> = Vec::with_capacity(self.joints.len());
        out.clear();
        for joint in &self.joints {
            let mut offset = Vector3::from(joint.offset);
            let mut local = Matrix3::identity();
            for (c, &channel) in joint.channels.iter().enumerate() {
                let v = row[joint.first_channel + c];
                match channel {
                    Channel::Xposition => offset.x = v,
                    Channel::Yposition => offset.y = v,
                    Channel::Zposition => offset.z = v,
                    Channel::Xrotation => local *= rotation(Vector3::x_axis(), v),
                    Channel::Yrotation => local *= rotation(Vector3::y_axis(), v),
                    Channel::Zrotation => local *= rotation(Vector3::z_axis(), v),
                }
            }
            let (position, global) = match joint.parent {
                Some(q) => (out[q] + rotations[q] * offset, rotations[q] * local),
                None => (offset, local),
            };
            out.push(position);
            rotations.push(global);
        }
    }

    /// Global positions of every joint in frame `t`.
    pub fn positions(&self, t: usize) -> Vec<Vector3<f64>> {
        let mut out = Vec::new();
        self.positions_into(t, &mut out);
        out
    }
}

fn rotation(axis: nalgebra::Unit<Vector3<f64>>, degrees: f64) -> Matrix3<f64> {
    Rotation3::from_axis_angle(&axis, degrees.to_radians()).into_inner()
}

fn parse_joint(
    tok: &mut Tokens<'_>,
    parent: Option<usize>,
    end_site: bool,
    joints: &mut Vec<BvhJoint>,
    channels: &mut usize,
) -> Result<(), BvhError> {
    let name = if end_site {
        tok.expect("Site")?;
        let parent_name = parent.map_or("", |q| joints[q].name.as_str());
        format!("{parent_name}_end")
    } else {
        tok.next("a joint name")?.1.to_string()
    };
    if joints.iter().any(|j| j.name == name) {
        return Err(BvhError::Syntax {
            line: tok.line(),
            detail: format!("joint `{name}` is defined twice"),
        });
    }
    tok.expect("{")?;
    tok.expect("OFFSET")?;
    let offset = [
        tok.number("an OFFSET value")?,
        tok.number("an OFFSET value")?,
        tok.number("an OFFSET value")?,
    ];
    let mut joint_channels = Vec::new();
    if !end_site
        && tok
            .peek()
            .is_some_and(|t| t.eq_ignore_ascii_case("CHANNELS"))
    {
        tok.pos += 1;
        let n = tok.number("the channel count")?;
        if !(0.0..=6.0).contains(&n) || n.fract() != 0.0 {
            return Err(BvhError::Syntax {
                line: tok.line(),
                detail: format!("joint `{name}` declares {n} channels (0 to 6 allowed)"),
            });
        }
        for _ in 0..n as usize {
            let (line, t) = tok.next("a channel name")?;
            let c = Channel::parse(t).ok_or_else(|| BvhError::Syntax {
                line,
                detail: format!("unknown channel `{t}` of joint `{name}`"),
            })?;
            if joint_channels.contains(&c) {
                return Err(BvhError::Syntax {
                    line,
                    detail: format!("channel `{t}` repeated on joint `{name}`"),
                });
            }
            joint_channels.push(c);
        }
    }
    let index = joints.len();
    let first_channel = *channels;
    *channels += joint_channels.len();
    joints.push(BvhJoint {
        name,
        parent,
        offset,
        channels: joint_channels,
        first_channel,
        end_site,
    });
    loop {
        let (line, t) = tok.next("`}`")?;
        if t == "}" {
            return Ok(());
        } else if end_site {
            return Err(BvhError::Syntax {
                line,
                detail: format!("expected `}}` closing an End Site, found `{t}`"),
            });
        } else if t.eq_ignore_ascii_case("JOINT") {
            parse_joint(tok, Some(index), false, joints, channels)?;
        } else if t.eq_ignore_ascii_case("End") {
            parse_joint(tok, Some(index), true, joints, channels)?;
        } else {
            return Err(BvhError::Syntax {
                line,
                detail: format!("expected `JOINT`, `End Site` or `}}`, found `{t}`"),
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TWO_LINKS: &str = "HIERARCHY
ROOT hips
{
  OFFSET 1 2 3
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT knee
  {
    OFFSET 0 -10 0
    CHANNELS 3 Xrotation Yrotation Zrotation
    End Site
    {
      OFFSET 0 -5 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.5
0 0 0 0 0 0 0 0 0
10 20 30 90 0 0 90 0 0
";

    #[test]
    fn forward_kinematics_follows_channel_order_and_position_channels() {
        let bvh = Bvh::parse(TWO_LINKS).expect("parses");
        assert_eq!(bvh.joints.len(), 3);
        assert_eq!(bvh.joints[2].name, "knee_end");
        assert_eq!((bvh.frames(), bvh.channels), (2, 9));
        // Frame 0: position channels (0, 0, 0) replace the root's offset (1, 2, 3).
        let p = bvh.positions(0);
        assert!((p[0] - Vector3::zeros()).norm() < 1e-12);
        assert!((p[1] - Vector3::new(0.0, -10.0, 0.0)).norm() < 1e-12);
        assert!((p[2] - Vector3::new(0.0, -15.0, 0.0)).norm() < 1e-12);
        // Frame 1: root at (10, 20, 30), turned 90 deg about z: -y maps to +x. The knee
        // then turns 90 deg about its x axis: its -y bone maps to -z locally, and -z
        // stays -z under the root's z rotation.
        let p = bvh.positions(1);
        assert!(
            (p[1] - Vector3::new(20.0, 20.0, 30.0)).norm() < 1e-9,
            "{}",
            p[1]
        );
        assert!(
            (p[2] - Vector3::new(20.0, 20.0, 25.0)).norm() < 1e-9,
            "{}",
            p[2]
        );
    }

    #[test]
    fn errors_name_the_line_and_the_problem() {
        let cases = [
            (
                TWO_LINKS.replace("Zrotation Xrotation", "Zrotation Wrotation"),
                "Wrotation",
            ),
            (
                TWO_LINKS.replace("OFFSET 0 -10 0", "OFFSET 0 nan 0"),
                "not finite",
            ),
            (TWO_LINKS.replace("Frames: 2", "Frames: 3"), "3 frames"),
            (TWO_LINKS.replace("JOINT knee", "JOINT hips"), "twice"),
            (TWO_LINKS.replace("MOTION", ""), "`MOTION`"),
            ("HIERARCHY\nMOTION\n".to_string(), "no ROOT"),
            (String::new(), "HIERARCHY"),
        ];
        for (text, needle) in cases {
            let e = Bvh::parse(&text).expect_err(needle).to_string();
            assert!(e.contains(needle), "`{e}` lacks `{needle}`");
        }
    }
}
