//! Enums of the layers below the binary taken on the command line by their names in the
//! configuration (serde's kebab-case): clap lives in the binary only, so those crates
//! derive no `clap::ValueEnum`; [`choice`] parses any [`Choice`] and lists its names
//! (with their help) in `--help`.

use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use serde::de::{DeserializeOwned, IntoDeserializer};

use posestream::detector::Runtime;
use posestream::models::LandmarkModel;
use posestream::synth::Projection;

/// An enum taken on the command line by its configuration name.
pub trait Choice: DeserializeOwned + Clone + Send + Sync + 'static {
    /// Each value's name (as the configuration spells it) and its help.
    const NAMES: &'static [(&'static str, &'static str)];
}

/// The parser of a [`Choice`]: one of its names, else clap's error listing them.
pub fn choice<T: Choice>() -> impl TypedValueParser<Value = T> {
    let names = T::NAMES
        .iter()
        .map(|&(name, help)| PossibleValue::new(name).help(help));
    PossibleValuesParser::new(names).try_map(|name: String| {
        T::deserialize(IntoDeserializer::<serde::de::value::Error>::into_deserializer(name))
    })
}

impl Choice for LandmarkModel {
    const NAMES: &'static [(&'static str, &'static str)] = &[
        ("lite", "pose_landmark_lite.tflite"),
        ("full", "pose_landmark_full.tflite"),
        ("heavy", "pose_landmark_heavy.tflite"),
    ];
}

impl Choice for Runtime {
    const NAMES: &'static [(&'static str, &'static str)] = &[
        (
            "auto",
            "LiteRT when it is set up (`posestream models fetch` fetches it, or litert_library, or $POSESTREAM_LITERT), else tract",
        ),
        ("tract", "tract, pure Rust (the rewritten models)"),
        (
            "litert",
            "Google's LiteRT with XNNPACK, loaded at run time (the original models)",
        ),
    ];
}

impl Choice for Projection {
    const NAMES: &'static [(&'static str, &'static str)] = &[
        (
            "orthographic",
            "Parallel projection at `focal / distance` pixels per metre (the same image size as the pinhole camera at the body's distance)",
        ),
        ("pinhole", "A pinhole camera with the given focal length"),
    ];
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every name parses to a value whose configuration name it is, and every value has
    /// a name.
    fn names_round_trip<T: Choice + serde::Serialize + PartialEq + std::fmt::Debug>(all: &[T]) {
        assert_eq!(T::NAMES.len(), all.len());
        for (name, _) in T::NAMES {
            let parsed: T = T::deserialize(
                IntoDeserializer::<serde::de::value::Error>::into_deserializer(*name),
            )
            .expect(name);
            assert!(all.contains(&parsed));
            assert_eq!(
                toml::Value::try_from(&parsed).expect("serialises").as_str(),
                Some(*name)
            );
        }
    }

    #[test]
    fn the_names_are_the_configurations() {
        names_round_trip(&LandmarkModel::ALL);
        names_round_trip(&[Runtime::Auto, Runtime::Tract, Runtime::Litert]);
        names_round_trip(&[Projection::Orthographic, Projection::Pinhole]);
    }

    #[test]
    fn other_names_are_refused() {
        use clap::Parser;
        #[derive(Debug, Parser)]
        struct Args {
            #[arg(long, value_parser = choice::<Runtime>())]
            runtime: Runtime,
        }
        assert_eq!(
            Args::try_parse_from(["x", "--runtime", "litert"])
                .expect("parses")
                .runtime,
            Runtime::Litert
        );
        assert!(Args::try_parse_from(["x", "--runtime", "gpu"]).is_err());
    }
}
