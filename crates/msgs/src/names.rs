//! ROS 2 names as posestream takes them from a configuration: absolute topic names
//! ([`check_topic_name`]), and the most bytes a frame id may have
//! ([`FRAME_ID_BYTES`]: the fixed shared-memory layouts hold no more).

use posestream_base::OutOfDomain;

/// Bytes of a frame id at most (NUL-padded UTF-8 in the shared-memory layouts,
/// `msgs/SHARED_MEMORY.md`).
pub const FRAME_ID_BYTES: usize = 64;

/// A token of a ROS name: letters, digits and `_`, not starting with a digit.
pub fn is_ros_token(t: &str) -> bool {
    t.chars()
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && t.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// Checks that `name` is an absolute ROS 2 topic name: `/` then tokens of letters,
/// digits and `_` (not starting with a digit) separated by single `/`.
pub fn check_topic_name(key: &str, name: &str) -> Result<(), OutOfDomain> {
    let ok = name.len() <= 255
        && name
            .strip_prefix('/')
            .is_some_and(|rest| rest.split('/').all(is_ros_token));
    if ok {
        Ok(())
    } else {
        Err(OutOfDomain::new(
            key,
            "an absolute ROS 2 topic name (/a/b_c: letters, digits, _ and single /)",
            format!("{name:?}"),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_absolute_names_of_ros_tokens_are_topic_names() {
        for good in ["/a", "/posestream/heatmaps", "/_x/y1"] {
            assert!(check_topic_name("topic", good).is_ok(), "{good}");
        }
        for bad in ["", "/", "a/b", "/a//b", "/1a", "/a-b", "/a/"] {
            assert!(check_topic_name("topic", bad).is_err(), "{bad}");
        }
    }
}
