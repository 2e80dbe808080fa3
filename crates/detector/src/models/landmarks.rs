//! A BlazePose landmark model run by `tract` (pure Rust, CPU): one 256 x 256 RGB crop
//! in, the heat maps (and the rest of the model's outputs) out.

use std::path::Path;

use tract_tflite::prelude::*;

/// Input side, pixels.
pub const INPUT_SIZE: usize = 256;
/// Heat-map side, cells (cell `c` covers input pixels `4c..4c+3`).
pub const HEATMAP_SIZE: usize = 64;
/// Heat-map channels: BlazePose's 33 landmarks, then 6 auxiliary ones.
pub const HEATMAP_CHANNELS: usize = 39;

/// Why the network could not be loaded or run.
#[derive(Debug, thiserror::Error)]
pub enum NetworkError {
    /// tract refused the model or the input.
    #[error("{context}: {reason}")]
    Tract {
        /// What was being done.
        context: String,
        /// tract's message.
        reason: String,
    },
    /// The model's outputs are not the expected ones.
    #[error("unexpected model outputs: {0}")]
    Outputs(String),
    /// LiteRT could not be loaded, or refused the model or a run.
    #[error("LiteRT: {context}: {reason}")]
    LiteRt {
        /// What was being done.
        context: String,
        /// Why it failed.
        reason: String,
    },
}

fn tract_error(context: impl Into<String>) -> impl FnOnce(TractError) -> NetworkError {
    let context = context.into();
    move |e| NetworkError::Tract {
        context,
        reason: format!("{e:#}"),
    }
}

/// What one run gives.
#[derive(Debug, Clone, PartialEq)]
pub struct LandmarkOutput {
    /// Heat-map logits, `64 x 64 x 39` (row, column, channel), as the model emits them:
    /// apply a sigmoid for scores.
    pub heatmap_logits: Vec<f32>,
    /// Probability that a person is in the crop.
    pub pose_flag: f32,
    /// 39 x (x, y, z, visibility, presence), input pixels for x and y.
    pub landmarks: Vec<f32>,
}

/// A loaded landmark model.
pub struct LandmarkNetwork {
    model: std::sync::Arc<TypedRunnableModel>,
}

/// Loads a model rewritten for tract ([`super::rewrite`]) and optimises it.
pub(crate) fn load_model(path: &Path) -> Result<std::sync::Arc<TypedRunnableModel>, NetworkError> {
    let what = || format!("loading {}", path.display());
    tract_tflite::tflite()
        .model_for_path(path)
        .map_err(tract_error(what()))?
        .into_optimized()
        .map_err(tract_error(what()))?
        .into_runnable()
        .map_err(tract_error(what()))
}

/// Runs `model` on one `f32` input of `shape`; returns its outputs.
pub(crate) fn run_model(
    model: &std::sync::Arc<TypedRunnableModel>,
    shape: &[usize],
    input: &[f32],
) -> Result<TVec<TValue>, NetworkError> {
    let n: usize = shape.iter().product();
    if input.len() != n {
        return Err(NetworkError::Tract {
            context: "the input".into(),
            reason: format!("{} values, expected {shape:?} = {n}", input.len()),
        });
    }
    let tensor = Tensor::from_shape(shape, input).map_err(tract_error("the input"))?;
    model
        .run(tvec!(tensor.into()))
        .map_err(tract_error("running the model"))
}

/// The values of the `f32` output of `shape`.
pub(crate) fn output_of_shape(
    outputs: &[TValue],
    shape: &[usize],
) -> Result<Vec<f32>, NetworkError> {
    outputs
        .iter()
        .find(|o| o.shape() == shape)
        .and_then(|o| o.to_plain_array_view::<f32>().ok())
        .map(|v| v.iter().copied().collect::<Vec<f32>>())
        .ok_or_else(|| NetworkError::Outputs(format!("no f32 output of shape {shape:?}")))
}

impl LandmarkNetwork {
    /// Loads a model rewritten for tract ([`super::rewrite`]) and optimises it.
    pub fn load(path: &Path) -> Result<Self, NetworkError> {
        Ok(Self {
            model: load_model(path)?,
        })
    }

    /// [`run`](Self::run) with the model's matrix products split across rayon's global
    /// pool (tract's multithreaded executor): for one crop at a time on several
    /// cores.
    pub fn run_spread(&self, rgb: &[f32]) -> Result<LandmarkOutput, NetworkError> {
        use tract_linalg::multithread::{Executor, multithread_tract_scope};
        multithread_tract_scope(Executor::RayonGlobal, || self.run(rgb))
    }

    /// Runs on one crop: `rgb` is `256 x 256 x 3`, row-major, values in [0, 1].
    pub fn run(&self, rgb: &[f32]) -> Result<LandmarkOutput, NetworkError> {
        let outputs = run_model(&self.model, &[1, INPUT_SIZE, INPUT_SIZE, 3], rgb)?;
        Ok(LandmarkOutput {
            heatmap_logits: output_of_shape(
                &outputs,
                &[1, HEATMAP_SIZE, HEATMAP_SIZE, HEATMAP_CHANNELS],
            )?,
            pose_flag: output_of_shape(&outputs, &[1, 1])?[0],
            landmarks: output_of_shape(&outputs, &[1, 195])?,
        })
    }
}
