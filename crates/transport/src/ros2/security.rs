//! DDS Security for the ROS 2 participant: an SROS2 keystore's enclave (identity
//! certificate and key, the certificate authorities, signed governance and permissions),
//! applied through RustDDS's built-in plugins (authentication, access control,
//! cryptography). Built with the crate's `security` feature (it links OpenSSL); a build
//! without it refuses a configuration that asks for security instead of running open.
//!
//! The ROS 2 conventions are followed: `ROS_SECURITY_ENABLE=true` turns it on,
//! `ROS_SECURITY_KEYSTORE` names the keystore, `ROS_SECURITY_ENCLAVE_OVERRIDE` the enclave,
//! and the enclave's folder is `<keystore>/enclaves/<enclave>` holding the files
//! `rmw_dds_common` names. Two differences: the default enclave is the node's full name
//! (ROS 2's is `/`), so that each node has its own grants; and security once asked for
//! is always enforced. ROS's default strategy (`Permissive`) runs an open participant
//! when the files are missing; a robot that quietly falls back to taking heat maps from
//! anyone is what access control is there to prevent, so here missing files are an
//! error.

use std::path::{Component, Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::setup_error;
use crate::TransportError;

/// The files of an enclave, as `rmw_dds_common` names them.
pub const ENCLAVE_FILES: [&str; 6] = [
    "identity_ca.cert.pem",
    "cert.pem",
    "key.pem",
    "permissions_ca.cert.pem",
    "governance.p7s",
    "permissions.p7s",
];

/// `[ros.security]`: DDS Security from an SROS2 keystore.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SecuritySettings {
    /// Join the domain with DDS Security only (`ROS_SECURITY_ENABLE=true` turns it on too).
    pub enable: bool,
    /// The keystore folder (the one holding `enclaves/`); `ROS_SECURITY_KEYSTORE` overrides it.
    pub keystore: String,
    /// The enclave: a path under the keystore's `enclaves/` ("" = the node's full name,
    /// `/posestream_estimator`); `ROS_SECURITY_ENCLAVE_OVERRIDE` overrides it.
    pub enclave: String,
}

impl SecuritySettings {
    /// The enclave folder to join with, `None` when security is off; `env` looks up
    /// environment variables (`ROS_SECURITY_*`). Every file the enclave needs must be
    /// there: the error names the missing ones.
    pub fn enclave_dir(
        &self,
        node_full_name: &str,
        env: impl Fn(&str) -> Option<String>,
    ) -> Result<Option<PathBuf>, TransportError> {
        let set = |k: &str| env(k).filter(|v| !v.trim().is_empty());
        let env_enable = set("ROS_SECURITY_ENABLE");
        let enabled = self.enable || env_enable.as_deref() == Some("true");
        if !enabled && let Some(v) = env_enable.filter(|v| v != "false") {
            // ROS 2 takes only `true`: say so rather than run open without a word.
            tracing::warn!("ROS_SECURITY_ENABLE={v:?} is not \"true\": DDS Security stays off");
        }
        if !enabled {
            return Ok(None);
        }
        let keystore = set("ROS_SECURITY_KEYSTORE").unwrap_or_else(|| self.keystore.clone());
        if keystore.trim().is_empty() {
            return Err(setup_error(
                "DDS Security",
                "no keystore: set [ros.security] keystore or ROS_SECURITY_KEYSTORE",
            ));
        }
        let enclave = set("ROS_SECURITY_ENCLAVE_OVERRIDE")
            .or_else(|| Some(self.enclave.clone()).filter(|e| !e.is_empty()))
            .unwrap_or_else(|| node_full_name.to_string());
        let relative = Path::new(enclave.trim_start_matches('/'));
        if !enclave.starts_with('/')
            || relative
                .components()
                .any(|c| !matches!(c, Component::Normal(_)))
        {
            return Err(setup_error(
                "DDS Security",
                format!(
                    "enclave {enclave:?} is not an absolute path without . or .. \
                     like /posestream_estimator"
                ),
            ));
        }
        let dir = Path::new(&keystore).join("enclaves").join(relative);
        if !dir.is_dir() {
            return Err(setup_error(
                format!("DDS Security (enclave {enclave})"),
                format!(
                    "no folder {} (make the enclave with tools/sros2-enclave, or check the \
                     keystore; a relative one is taken from the working directory)",
                    dir.display()
                ),
            ));
        }
        let missing: Vec<&str> = ENCLAVE_FILES
            .iter()
            .copied()
            .filter(|f| !dir.join(f).is_file())
            .collect();
        if !missing.is_empty() {
            return Err(setup_error(
                format!("DDS Security (enclave {enclave})"),
                format!("{} lacks {}", dir.display(), missing.join(", ")),
            ));
        }
        Ok(Some(dir))
    }
}

/// The participant builder with the enclave's security applied.
#[cfg(feature = "security")]
pub(super) fn secure(
    builder: ros2_client::dds::rustdds::DomainParticipantBuilder,
    enclave: &Path,
) -> Result<ros2_client::dds::rustdds::DomainParticipantBuilder, TransportError> {
    use ros2_client::dds::rustdds::DomainParticipantSecurityConfigFiles;
    // SROS2 writes unencrypted PKCS#8 keys; RustDDS reads no encrypted ones either.
    Ok(builder.builtin_security(
        DomainParticipantSecurityConfigFiles::with_ros_default_names(enclave, String::new()),
    ))
}

/// Without the `security` feature no participant can be secured: refuse.
#[cfg(not(feature = "security"))]
pub(super) fn secure(
    _builder: ros2_client::dds::rustdds::DomainParticipantBuilder,
    enclave: &Path,
) -> Result<ros2_client::dds::rustdds::DomainParticipantBuilder, TransportError> {
    Err(setup_error(
        "DDS Security",
        format!(
            "enclave {} asked for, but this build has no DDS Security: rebuild with \
             `cargo build --release --features security` (needs OpenSSL: libssl-dev, pkg-config)",
            enclave.display()
        ),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn enclave_with(files: &[&str]) -> tempfile::TempDir {
        let dir = tempfile::tempdir().expect("tempdir");
        let e = dir.path().join("enclaves/posestream_estimator");
        std::fs::create_dir_all(&e).expect("mkdir");
        for f in files {
            std::fs::write(e.join(f), "x").expect("write");
        }
        dir
    }

    #[cfg(not(feature = "security"))]
    #[test]
    fn a_build_without_the_feature_refuses_instead_of_running_open() {
        let builder = ros2_client::dds::rustdds::DomainParticipantBuilder::new(0);
        let e = secure(builder, Path::new("/k/enclaves/n"))
            .err()
            .expect("refused");
        assert!(e.to_string().contains("--features security"), "{e}");
    }

    #[test]
    fn not_on_loopback_only() {
        let store = enclave_with(&ENCLAVE_FILES);
        let settings = crate::ros2::RosSettings {
            localhost_only: true,
            node_name: "posestream_estimator".into(),
            security: SecuritySettings {
                enable: true,
                keystore: store.path().to_string_lossy().to_string(),
                enclave: String::new(),
            },
            ..Default::default()
        };
        let e = crate::ros2::Ros2::new(&settings).err().expect("refused");
        assert!(e.to_string().contains("not with localhost_only"), "{e}");
    }

    #[test]
    fn off_unless_asked_for() {
        let s = SecuritySettings::default();
        assert_eq!(s.enclave_dir("/n", |_| None).expect("off"), None);
        let env = |k: &str| (k == "ROS_SECURITY_ENABLE").then(|| "false".to_string());
        assert_eq!(s.enclave_dir("/n", env).expect("off"), None);
    }

    #[test]
    fn the_environment_turns_it_on_and_names_keystore_and_enclave() {
        let store = enclave_with(&ENCLAVE_FILES);
        let path = store.path().to_string_lossy().to_string();
        let env = |k: &str| match k {
            "ROS_SECURITY_ENABLE" => Some("true".to_string()),
            "ROS_SECURITY_KEYSTORE" => Some(path.clone()),
            _ => None,
        };
        let dir = SecuritySettings::default()
            .enclave_dir("/posestream_estimator", env)
            .expect("resolves")
            .expect("on");
        assert_eq!(dir, store.path().join("enclaves/posestream_estimator"));
        // The override wins over the node's name.
        let env = |k: &str| match k {
            "ROS_SECURITY_ENCLAVE_OVERRIDE" => Some("/elsewhere".to_string()),
            _ => None,
        };
        let s = SecuritySettings {
            enable: true,
            keystore: path.clone(),
            enclave: String::new(),
        };
        let e = s.enclave_dir("/posestream_estimator", env).unwrap_err();
        assert!(e.to_string().contains("enclave /elsewhere"), "{e}");
    }

    #[test]
    fn missing_files_and_bad_enclaves_are_errors_naming_them() {
        let store = enclave_with(&["cert.pem", "key.pem"]);
        let s = SecuritySettings {
            enable: true,
            keystore: store.path().to_string_lossy().to_string(),
            enclave: String::new(),
        };
        let e = s
            .enclave_dir("/posestream_estimator", |_| None)
            .unwrap_err();
        let text = e.to_string();
        assert!(text.contains("identity_ca.cert.pem"), "{text}");
        assert!(text.contains("permissions.p7s"), "{text}");
        assert!(!text.contains("key.pem,"), "{text}");
        for bad in ["relative", "/../../etc", "/a/../b"] {
            let s = SecuritySettings {
                enclave: bad.to_string(),
                ..s.clone()
            };
            let e = s.enclave_dir("/n", |_| None).unwrap_err();
            assert!(e.to_string().contains("not an absolute path"), "{bad}: {e}");
        }
        let s = SecuritySettings {
            keystore: String::new(),
            ..s
        };
        let e = s.enclave_dir("/n", |_| None).unwrap_err();
        assert!(e.to_string().contains("ROS_SECURITY_KEYSTORE"), "{e}");
    }
}
