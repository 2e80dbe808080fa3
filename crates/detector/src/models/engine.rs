//! A detector network on either runtime: tract's optimised plan (run by any number of
//! threads at once), or LiteRT's compiled models, one per worker of the parallel runs
//! (and, if asked for, one on all their cores for a lone run).
//! BlazePose's person detector ([`super::person`]) and the pedestrian detector
//! ([`super::pedestrians`]) load and run through it, each naming its input side and its
//! outputs.

use std::path::Path;
use std::sync::Arc;

use tract_tflite::prelude::*;

use super::landmarks::{NetworkError, load_model, output_of_shape, run_model};
use super::litert::{CompiledModels, LiteRt, LiteRtNetwork};

/// One output of a detector network: its shape in tract's plan and, the same values,
/// its size in floats for LiteRT (which names outputs by size).
#[derive(Debug, Clone, Copy)]
pub struct Output<'a> {
    /// The output's shape (tract).
    pub shape: &'a [usize],
    /// Its values, in floats (LiteRT).
    pub floats: usize,
}

/// What runs a detector network.
pub(crate) enum Engine {
    /// tract: one optimised plan.
    Tract(Arc<TypedRunnableModel>),
    /// LiteRT: compiled for parallel runs (and, if asked for, a lone run).
    LiteRt(CompiledModels),
}

impl Engine {
    /// The model at `path` for tract.
    pub fn tract(path: &Path) -> Result<Self, NetworkError> {
        Ok(Self::Tract(load_model(path)?))
    }

    /// The model at `path` compiled by LiteRT, once per worker of parallel runs (and,
    /// if `lone`, once on all their threads for a lone run), for an input of
    /// `side x side x 3` and `outputs`.
    pub fn litert(
        runtime: &LiteRt,
        path: &Path,
        workers: usize,
        lone: bool,
        side: usize,
        outputs: &[Output<'_>],
    ) -> Result<Self, NetworkError> {
        let floats: Vec<usize> = outputs.iter().map(|o| o.floats).collect();
        Ok(Self::LiteRt(CompiledModels::load(
            workers,
            lone,
            |threads| LiteRtNetwork::load_model(runtime, path, side * side * 3, &floats, threads),
        )?))
    }

    /// The model at `path` compiled by LiteRT once, to run on `threads` threads, for an
    /// input of `[rows, columns]` x 3 and `outputs`.
    pub fn litert_threads(
        runtime: &LiteRt,
        path: &Path,
        threads: usize,
        [rows, columns]: [usize; 2],
        outputs: &[Output<'_>],
    ) -> Result<Self, NetworkError> {
        let floats: Vec<usize> = outputs.iter().map(|o| o.floats).collect();
        let model =
            LiteRtNetwork::load_model(runtime, path, rows * columns * 3, &floats, threads.max(1))?;
        Ok(Self::LiteRt(CompiledModels::one(model)))
    }

    /// Runs every compiled model (tract: the plan) once on zeros of `[rows, columns]`
    /// x 3, before the first frame.
    pub fn warm_up(&self, [rows, columns]: [usize; 2]) -> Result<(), NetworkError> {
        let floats = rows * columns * 3;
        match self {
            Self::Tract(model) => {
                run_model(model, &[1, rows, columns, 3], &vec![0.0; floats]).map(drop)
            }
            Self::LiteRt(models) => models.warm_up(floats),
        }
    }

    /// Runs on `input` (`rows x columns x 3`, row-major); `worker` picks LiteRT's
    /// compiled model (`None`: the lone run's). The values of each of `outputs`, in
    /// their order.
    pub fn run<const N: usize>(
        &self,
        worker: Option<usize>,
        [rows, columns]: [usize; 2],
        input: &[f32],
        outputs: [Output<'_>; N],
    ) -> Result<[Vec<f32>; N], NetworkError> {
        let mut values: [Vec<f32>; N] = std::array::from_fn(|_| Vec::new());
        match self {
            Self::Tract(model) => {
                let out = run_model(model, &[1, rows, columns, 3], input)?;
                for (v, o) in values.iter_mut().zip(&outputs) {
                    *v = output_of_shape(&out, o.shape)?;
                }
            }
            Self::LiteRt(models) => {
                let mut net = models.lock(worker)?;
                net.run_raw(input)?;
                for (v, o) in values.iter_mut().zip(&outputs) {
                    *v = net.output(o.floats)?.to_vec();
                }
            }
        }
        Ok(values)
    }
}

/// A single-shot detector network: its input, its two outputs, its anchors, and how its
/// raw outputs become what it found ([`Network`] runs it on tract or LiteRT).
pub trait Detector {
    /// Input side, pixels (`side x side x 3`).
    const INPUT_SIZE: usize;
    /// Its two outputs, in order.
    const OUTPUTS: [Output<'static>; 2];
    /// Whether LiteRT also compiles a model on all the workers' threads for a lone run.
    const LONE_RUN: bool;
    /// One anchor.
    type Anchor;
    /// The raw outputs of one run.
    type Raw;
    /// What it finds.
    type Found;
    /// Its anchors, in the order of its outputs.
    fn anchors() -> Vec<Self::Anchor>;
    /// The raw outputs of one run, from its two outputs' values.
    fn raw(outputs: [Vec<f32>; 2]) -> Self::Raw;
    /// What `raw` finds scoring at least `threshold`, best first.
    fn found(raw: &Self::Raw, anchors: &[Self::Anchor], threshold: f32) -> Vec<Self::Found>;
}

/// A loaded [`Detector`].
pub struct Network<D: Detector> {
    engine: Engine,
    anchors: Vec<D::Anchor>,
}

impl<D: Detector> Network<D> {
    /// Loads the model at `path` (rewritten or converted for tract) for tract.
    pub fn load(path: &Path) -> Result<Self, NetworkError> {
        Ok(Self {
            engine: Engine::tract(path)?,
            anchors: D::anchors(),
        })
    }

    /// Compiles the model at `path` with LiteRT, one compiled model per worker of
    /// parallel runs (and one for a lone run: [`Detector::LONE_RUN`]).
    pub fn load_litert(
        runtime: &LiteRt,
        path: &Path,
        workers: usize,
    ) -> Result<Self, NetworkError> {
        Ok(Self {
            engine: Engine::litert(
                runtime,
                path,
                workers,
                D::LONE_RUN,
                D::INPUT_SIZE,
                &D::OUTPUTS,
            )?,
            anchors: D::anchors(),
        })
    }

    /// Runs every compiled model once, before the first frame ([`Engine::warm_up`]).
    pub fn warm_up(&self) -> Result<(), NetworkError> {
        self.engine.warm_up([D::INPUT_SIZE; 2])
    }

    /// Raw outputs for `input`: `INPUT_SIZE x INPUT_SIZE x 3`, row-major, values in
    /// [-1, 1]; `worker` picks LiteRT's compiled model (`None`: the lone run's).
    pub fn run_raw(&self, worker: Option<usize>, input: &[f32]) -> Result<D::Raw, NetworkError> {
        let outputs = self
            .engine
            .run(worker, [D::INPUT_SIZE; 2], input, D::OUTPUTS)?;
        Ok(D::raw(outputs))
    }

    /// What `input` holds scoring at least `threshold`, best first.
    pub fn detect(
        &self,
        worker: Option<usize>,
        input: &[f32],
        threshold: f32,
    ) -> Result<Vec<D::Found>, NetworkError> {
        let raw = self.run_raw(worker, input)?;
        Ok(D::found(&raw, &self.anchors, threshold))
    }
}
