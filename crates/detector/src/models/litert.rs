//! Google's LiteRT as the landmark model's runtime: `libLiteRt.so` of the PyPI wheel
//! `ai-edge-litert` (2.3), XNNPACK on the CPU, loaded at run time through its C API
//! (`libloading`), on the original model files (no rewrite).
//!
//! Why: on this project's 2-core machine tract runs the full landmark model in 40-75 ms
//! and LiteRT in 18-25 ms (docs/speed.md: `cargo bench --bench detector`
//! beside `benches/litert.py`); the real-time goals need the latter. Why by hand: no
//! maintained crate binds LiteRT's C API without building TensorFlow from source. The
//! binding is the few calls of a compiled model with host-memory buffers; the C API is
//! not stable across LiteRT versions (`LiteRtCreateModelFromFile` gained its
//! environment argument in 2.x), so the library's wheel version is checked first and
//! anything but 2.3 is refused.
//!
//! A [`LiteRtNetwork`] is one compiled model with its buffers: not for two threads at
//! once (the detector keeps one per worker, and one on every worker's core for a
//! frame's lone run: [`CompiledModels`]).

#![allow(
    unsafe_code,
    reason = "an FFI binding: each call's contract is stated where it is made"
)]

use std::ffi::{CString, c_char, c_int, c_void};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::landmarks::{HEATMAP_CHANNELS, HEATMAP_SIZE, INPUT_SIZE, LandmarkOutput, NetworkError};

type Handle = *mut c_void;
type Status = c_int;
type Deallocator = Option<unsafe extern "C" fn(*mut c_void)>;

/// LiteRT's CPU accelerator (`kLiteRtHwAcceleratorCpu`).
const ACCELERATOR_CPU: c_int = 1;
/// Host buffers are aligned to this (`LITERT_HOST_MEMORY_BUFFER_ALIGNMENT`).
const ALIGNMENT: usize = 64;
/// Bytes kept for a `LiteRtRankedTensorType` (an element type and a layout of at most
/// 8 dimensions and strides: under 100 bytes in 2.3).
const TENSOR_TYPE_BYTES: usize = 512;
/// The wheel version whose C API this binds.
const BOUND_VERSION: &str = "2.3.";

fn error(context: &str, reason: impl Into<String>) -> NetworkError {
    NetworkError::LiteRt {
        context: context.into(),
        reason: reason.into(),
    }
}

/// The C API's functions used here.
struct Api {
    create_environment: unsafe extern "C" fn(c_int, *const c_void, *mut Handle) -> Status,
    destroy_environment: unsafe extern "C" fn(Handle),
    create_model_from_file: unsafe extern "C" fn(Handle, *const c_char, *mut Handle) -> Status,
    destroy_model: unsafe extern "C" fn(Handle),
    create_options: unsafe extern "C" fn(*mut Handle) -> Status,
    destroy_options: unsafe extern "C" fn(Handle),
    set_accelerators: unsafe extern "C" fn(Handle, c_int) -> Status,
    create_opaque_options:
        unsafe extern "C" fn(*const c_char, *mut c_void, Deallocator, *mut Handle) -> Status,
    add_opaque_options: unsafe extern "C" fn(Handle, Handle) -> Status,
    destroy_opaque_options: unsafe extern "C" fn(Handle),
    create_compiled_model: unsafe extern "C" fn(Handle, Handle, Handle, *mut Handle) -> Status,
    destroy_compiled_model: unsafe extern "C" fn(Handle),
    model_signature: unsafe extern "C" fn(Handle, usize, *mut Handle) -> Status,
    signature_inputs: unsafe extern "C" fn(Handle, *mut usize) -> Status,
    signature_outputs: unsafe extern "C" fn(Handle, *mut usize) -> Status,
    signature_input: unsafe extern "C" fn(Handle, usize, *mut Handle) -> Status,
    signature_output: unsafe extern "C" fn(Handle, usize, *mut Handle) -> Status,
    ranked_tensor_type: unsafe extern "C" fn(Handle, *mut u8) -> Status,
    buffer_from_host_memory:
        unsafe extern "C" fn(*const u8, *mut c_void, usize, Deallocator, *mut Handle) -> Status,
    buffer_packed_size: unsafe extern "C" fn(Handle, *mut usize) -> Status,
    destroy_buffer: unsafe extern "C" fn(Handle),
    run: unsafe extern "C" fn(Handle, usize, usize, *mut Handle, usize, *mut Handle) -> Status,
    /// Never unloaded: LiteRT registers exit handlers that must find its code in
    /// memory (unloading it made every exit after an error a segmentation fault).
    _library: std::mem::ManuallyDrop<libloading::Library>,
}

/// A loaded `libLiteRt.so`.
#[derive(Clone)]
pub struct LiteRt {
    api: Arc<Api>,
}

impl std::fmt::Debug for LiteRt {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("LiteRt")
    }
}

/// The version of the `ai-edge-litert` wheel `library` came with: its package folder's
/// sibling `ai_edge_litert-<version>.dist-info`.
pub fn wheel_version(library: &Path) -> Option<String> {
    let site = library.parent()?.parent()?;
    std::fs::read_dir(site).ok()?.find_map(|e| {
        let name = e.ok()?.file_name().into_string().ok()?;
        name.strip_prefix("ai_edge_litert-")?
            .strip_suffix(".dist-info")
            .map(str::to_string)
    })
}

impl LiteRt {
    /// Loads `library` (`.../site-packages/ai_edge_litert/libLiteRt.so` of
    /// `pip install ai-edge-litert==2.3.*`).
    pub fn load(library: &Path) -> Result<Self, NetworkError> {
        let context = format!("loading {}", library.display());
        if !library.is_file() {
            return Err(error(
                &context,
                if library.exists() {
                    "not a file"
                } else {
                    "no such file"
                },
            ));
        }
        match wheel_version(library) {
            Some(v) if v.starts_with(BOUND_VERSION) => {}
            Some(v) => {
                return Err(error(
                    &context,
                    format!(
                        "ai-edge-litert {v}: posestream binds the C API of 2.3 (pip install 'ai-edge-litert==2.3.*')"
                    ),
                ));
            }
            None => {
                return Err(error(
                    &context,
                    "not the libLiteRt.so of an ai-edge-litert wheel (no ai_edge_litert-*.dist-info beside its folder): \
                     pip install 'ai-edge-litert==2.3.*' and name site-packages/ai_edge_litert/libLiteRt.so",
                ));
            }
        }
        // SAFETY: loading runs the library's initialisers; it is LiteRT's own shared
        // library of the checked wheel version, which has no unsound initialisers.
        let library = unsafe { libloading::Library::new(library) }
            .map_err(|e| error(&context, e.to_string()))?;
        macro_rules! symbol {
            ($name:literal) => {
                // SAFETY: the symbol's type is its declaration in LiteRT 2.3's C headers
                // (litert/c/*.h), transcribed in `Api`; the pointer is used only while
                // `_library` is alive (it is dropped last).
                *unsafe { library.get($name) }.map_err(|e| error(&context, e.to_string()))?
            };
        }
        let api = Api {
            create_environment: symbol!(b"LiteRtCreateEnvironment\0"),
            destroy_environment: symbol!(b"LiteRtDestroyEnvironment\0"),
            create_model_from_file: symbol!(b"LiteRtCreateModelFromFile\0"),
            destroy_model: symbol!(b"LiteRtDestroyModel\0"),
            create_options: symbol!(b"LiteRtCreateOptions\0"),
            destroy_options: symbol!(b"LiteRtDestroyOptions\0"),
            set_accelerators: symbol!(b"LiteRtSetOptionsHardwareAccelerators\0"),
            create_opaque_options: symbol!(b"LiteRtCreateOpaqueOptions\0"),
            add_opaque_options: symbol!(b"LiteRtAddOpaqueOptions\0"),
            destroy_opaque_options: symbol!(b"LiteRtDestroyOpaqueOptions\0"),
            create_compiled_model: symbol!(b"LiteRtCreateCompiledModel\0"),
            destroy_compiled_model: symbol!(b"LiteRtDestroyCompiledModel\0"),
            model_signature: symbol!(b"LiteRtGetModelSignature\0"),
            signature_inputs: symbol!(b"LiteRtGetNumSignatureInputs\0"),
            signature_outputs: symbol!(b"LiteRtGetNumSignatureOutputs\0"),
            signature_input: symbol!(b"LiteRtGetSignatureInputTensorByIndex\0"),
            signature_output: symbol!(b"LiteRtGetSignatureOutputTensorByIndex\0"),
            ranked_tensor_type: symbol!(b"LiteRtGetRankedTensorType\0"),
            buffer_from_host_memory: symbol!(b"LiteRtCreateTensorBufferFromHostMemory\0"),
            buffer_packed_size: symbol!(b"LiteRtGetTensorBufferPackedSize\0"),
            destroy_buffer: symbol!(b"LiteRtDestroyTensorBuffer\0"),
            run: symbol!(b"LiteRtRunCompiledModel\0"),
            _library: std::mem::ManuallyDrop::new(library),
        };
        Ok(Self { api: Arc::new(api) })
    }

    /// The library named by `path`, else `$POSESTREAM_LITERT`.
    pub fn library_path(path: &Path) -> Option<PathBuf> {
        if !path.as_os_str().is_empty() {
            return Some(path.to_path_buf());
        }
        std::env::var_os("POSESTREAM_LITERT")
            .filter(|p| !p.is_empty())
            .map(PathBuf::from)
    }
}

/// Frees an options payload made by `CString::into_raw` (LiteRT calls it once, when it
/// destroys the options holding it).
unsafe extern "C" fn free_payload(payload: *mut c_void) {
    // SAFETY: `payload` came from `CString::into_raw` and is freed once, here.
    drop(unsafe { CString::from_raw(payload.cast::<c_char>()) });
}

/// One tensor's host memory: 64-byte aligned floats inside `memory`.
struct Buffer {
    memory: Vec<f32>,
    offset: usize,
    floats: usize,
    handle: Handle,
}

impl Buffer {
    fn values(&self) -> &[f32] {
        &self.memory[self.offset..self.offset + self.floats]
    }

    fn values_mut(&mut self) -> &mut [f32] {
        &mut self.memory[self.offset..self.offset + self.floats]
    }
}

/// The landmark model compiled by LiteRT for the CPU, with its buffers.
pub struct LiteRtNetwork {
    runtime: LiteRt,
    environment: Handle,
    model: Handle,
    options: Handle,
    compiled: Handle,
    inputs: Vec<Buffer>,
    outputs: Vec<Buffer>,
    input_handles: Vec<Handle>,
    output_handles: Vec<Handle>,
}

// SAFETY: the handles are owned by this value alone and LiteRT's objects are not tied
// to the thread that made them; `&mut self` for every call keeps one thread at a time.
unsafe impl Send for LiteRtNetwork {}

impl LiteRtNetwork {
    /// Compiles the original (not rewritten) landmark model at `path`, each run on
    /// `threads` threads (XNNPACK's).
    pub fn load(runtime: &LiteRt, path: &Path, threads: usize) -> Result<Self, NetworkError> {
        Self::load_model(
            runtime,
            path,
            INPUT_SIZE * INPUT_SIZE * 3,
            &[HEATMAP_SIZE * HEATMAP_SIZE * HEATMAP_CHANNELS, 1, 195],
            threads,
        )
    }

    /// Compiles the model at `path`: one input of `input_floats`, outputs of (at least)
    /// each size of `output_floats`, each run on `threads` threads (XNNPACK's own pool;
    /// 1: the calling thread only).
    pub fn load_model(
        runtime: &LiteRt,
        path: &Path,
        input_floats: usize,
        output_floats: &[usize],
        threads: usize,
    ) -> Result<Self, NetworkError> {
        let context = format!("loading {}", path.display());
        let ctx = context.as_str();
        let api = runtime.api.clone();
        let file = CString::new(path.as_os_str().as_encoded_bytes())
            .map_err(|_| error(ctx, "a NUL in the path"))?;
        let mut net = Self {
            runtime: runtime.clone(),
            environment: std::ptr::null_mut(),
            model: std::ptr::null_mut(),
            options: std::ptr::null_mut(),
            compiled: std::ptr::null_mut(),
            inputs: Vec::new(),
            outputs: Vec::new(),
            input_handles: Vec::new(),
            output_handles: Vec::new(),
        };
        let check = |status: Status, what: &str| {
            if status == 0 {
                Ok(())
            } else {
                Err(error(ctx, format!("{what}: status {status}")))
            }
        };
        // LiteRT logs what it does here on stderr: passed through `tracing` instead.
        // SAFETY: each out-pointer is a live local or field; handles passed in were
        // made by the calls before and are not yet destroyed (`Drop` destroys them
        // once, in reverse order).
        super::litert_log::quietly(|| unsafe {
            check(
                (api.create_environment)(0, std::ptr::null(), &raw mut net.environment),
                "the environment",
            )?;
            check(
                (api.create_model_from_file)(net.environment, file.as_ptr(), &raw mut net.model),
                "the model",
            )?;
            check((api.create_options)(&raw mut net.options), "the options")?;
            check(
                (api.set_accelerators)(net.options, ACCELERATOR_CPU),
                "the CPU",
            )?;
            // The CPU accelerator's options: LiteRT's "xnnpack" opaque options, a TOML
            // payload (litert/c/options/litert_cpu_options.cc of the 2.x sources; that
            // helper is not exported by the wheel's library, the calls below are). The
            // opaque options own the payload once made (they free it with
            // `free_payload`), the options own them once added (`Drop` destroys both).
            let payload = CString::new(format!("num_threads = {}\n", threads.clamp(1, 64)))
                .map_err(|_| error(ctx, "the CPU options"))?;
            let mut opaque: Handle = std::ptr::null_mut();
            let payload = payload.into_raw().cast::<c_void>();
            let status = (api.create_opaque_options)(
                c"xnnpack".as_ptr(),
                payload,
                Some(free_payload),
                &raw mut opaque,
            );
            if status != 0 {
                // Not taken: still ours.
                free_payload(payload);
            }
            check(status, "the CPU options")?;
            let status = (api.add_opaque_options)(net.options, opaque);
            if status != 0 {
                // Not taken: still ours (with the payload).
                (api.destroy_opaque_options)(opaque);
            }
            check(status, "the CPU options")?;
            check(
                (api.create_compiled_model)(
                    net.environment,
                    net.model,
                    net.options,
                    &raw mut net.compiled,
                ),
                "compiling",
            )
        })?;
        // SAFETY: as above.
        unsafe {
            let mut signature: Handle = std::ptr::null_mut();
            check(
                (api.model_signature)(net.model, 0, &raw mut signature),
                "its signature",
            )?;
            let (mut n_in, mut n_out) = (0usize, 0usize);
            check(
                (api.signature_inputs)(signature, &raw mut n_in),
                "its inputs",
            )?;
            check(
                (api.signature_outputs)(signature, &raw mut n_out),
                "its outputs",
            )?;
            if n_in != 1 || n_out > 16 {
                return Err(error(ctx, format!("{n_in} inputs, {n_out} outputs")));
            }
            for (count, input) in [(n_in, true), (n_out, false)] {
                for i in 0..count {
                    let mut tensor: Handle = std::ptr::null_mut();
                    let getter = if input {
                        api.signature_input
                    } else {
                        api.signature_output
                    };
                    check(getter(signature, i, &raw mut tensor), "a tensor")?;
                    // 8-byte aligned, as the struct LiteRT writes there.
                    let mut kind = [0u64; TENSOR_TYPE_BYTES / 8];
                    check(
                        (api.ranked_tensor_type)(tensor, kind.as_mut_ptr().cast::<u8>()),
                        "its type",
                    )?;
                    let buffer = net.host_buffer(&kind, ctx)?;
                    if input {
                        net.inputs.push(buffer);
                    } else {
                        net.outputs.push(buffer);
                    }
                }
            }
        }
        net.input_handles = net.inputs.iter().map(|b| b.handle).collect();
        net.output_handles = net.outputs.iter().map(|b| b.handle).collect();
        let want = input_floats;
        if net.inputs[0].floats != want {
            return Err(error(
                ctx,
                format!("input of {} floats, expected {want}", net.inputs[0].floats),
            ));
        }
        for &n in output_floats {
            if !net.outputs.iter().any(|b| b.floats == n) {
                return Err(error(ctx, format!("no output of {n} floats")));
            }
        }
        Ok(net)
    }

    /// A host buffer for a tensor of type `kind` (made by `LiteRtGetRankedTensorType`).
    fn host_buffer(&self, kind: &[u64], ctx: &str) -> Result<Buffer, NetworkError> {
        let api = &self.runtime.api;
        // Generous room first; the packed size the buffer reports is the tensor's.
        const ROOM_FLOATS: usize = 1 << 20;
        let mut memory = vec![0f32; ROOM_FLOATS + ALIGNMENT / 4];
        let offset = memory.as_ptr().align_offset(ALIGNMENT);
        if offset >= ALIGNMENT / 4 {
            return Err(error(ctx, "cannot align a host buffer"));
        }
        let mut handle: Handle = std::ptr::null_mut();
        let mut packed = 0usize;
        // SAFETY: `kind` holds a tensor type LiteRT wrote; the memory (aligned, of the
        // size given) lives in the returned `Buffer` as long as the handle (`Drop`
        // destroys the handle first); no deallocator: the memory is ours.
        let status = unsafe {
            let base = memory.as_mut_ptr().add(offset).cast::<c_void>();
            (api.buffer_from_host_memory)(
                kind.as_ptr().cast::<u8>(),
                base,
                ROOM_FLOATS * 4,
                None,
                &raw mut handle,
            )
        };
        if status != 0 {
            return Err(error(ctx, format!("a host buffer: status {status}")));
        }
        // SAFETY: `handle` was just made.
        let status = unsafe { (api.buffer_packed_size)(handle, &raw mut packed) };
        if status != 0 || !packed.is_multiple_of(4) || packed / 4 > ROOM_FLOATS {
            // SAFETY: made above, not destroyed elsewhere.
            unsafe { (api.destroy_buffer)(handle) };
            return Err(error(
                ctx,
                format!("a tensor of {packed} bytes (status {status})"),
            ));
        }
        Ok(Buffer {
            memory,
            offset,
            floats: packed / 4,
            handle,
        })
    }

    /// Runs on `input` (the model's one input, row-major floats); the outputs are
    /// then read with [`output`](Self::output).
    pub fn run_raw(&mut self, input: &[f32]) -> Result<(), NetworkError> {
        let slot = self.inputs[0].values_mut();
        if input.len() != slot.len() {
            return Err(error(
                "the input",
                format!("{} values, expected {}", input.len(), slot.len()),
            ));
        }
        slot.copy_from_slice(input);
        let api = &self.runtime.api;
        // SAFETY: the compiled model and the buffers' handles are live (destroyed only
        // in `Drop`); the handle arrays hold exactly the counts passed.
        let status = unsafe {
            (api.run)(
                self.compiled,
                0,
                self.input_handles.len(),
                self.input_handles.as_mut_ptr(),
                self.output_handles.len(),
                self.output_handles.as_mut_ptr(),
            )
        };
        if status != 0 {
            return Err(error("running the model", format!("status {status}")));
        }
        Ok(())
    }

    /// The output of `floats` values of the last run.
    pub fn output(&self, floats: usize) -> Result<&[f32], NetworkError> {
        self.outputs
            .iter()
            .find(|b| b.floats == floats)
            .map(Buffer::values)
            .ok_or_else(|| NetworkError::Outputs(format!("no output of {floats} floats")))
    }

    /// Runs the landmark model on one crop: `rgb` is `256 x 256 x 3`, row-major, values
    /// in [0, 1].
    pub fn run(&mut self, rgb: &[f32]) -> Result<LandmarkOutput, NetworkError> {
        self.run_raw(rgb)?;
        Ok(LandmarkOutput {
            heatmap_logits: self
                .output(HEATMAP_SIZE * HEATMAP_SIZE * HEATMAP_CHANNELS)?
                .to_vec(),
            pose_flag: self.output(1)?[0],
            landmarks: self.output(195)?.to_vec(),
        })
    }
}

impl Drop for LiteRtNetwork {
    fn drop(&mut self) {
        let api = &self.runtime.api;
        // SAFETY: each non-null handle was made once by `load` and is destroyed once
        // here, users before what they use. LiteRT logs the teardown (`tracing` here).
        super::litert_log::quietly(|| unsafe {
            for b in self.inputs.iter().chain(&self.outputs) {
                (api.destroy_buffer)(b.handle);
            }
            if !self.compiled.is_null() {
                (api.destroy_compiled_model)(self.compiled);
            }
            if !self.options.is_null() {
                (api.destroy_options)(self.options);
            }
            if !self.model.is_null() {
                (api.destroy_model)(self.model);
            }
            if !self.environment.is_null() {
                (api.destroy_environment)(self.environment);
            }
        });
    }
}

/// One network compiled by LiteRT for parallel and lone runs: one compiled model per
/// worker of the parallel runs (a compiled model runs one input at a time), each on its
/// worker's thread, and one for a frame's lone run on all the workers' cores
/// (XNNPACK's own threads).
/// (`N`: the compiled model, [`LiteRtNetwork`]; anything in tests.)
pub struct CompiledModels<N = LiteRtNetwork> {
    /// One per worker of the parallel runs, one thread each.
    workers: Vec<std::sync::Mutex<N>>,
    /// A frame's only run: XNNPACK's threads, one per worker (`None` with one worker,
    /// or when not asked for: the first worker's model).
    lone: Option<std::sync::Mutex<N>>,
}

impl<N> CompiledModels<N> {
    /// `load(threads)` once per worker (one thread each) and, if `lone` and there are
    /// several workers, once on `workers` threads.
    pub fn load(
        workers: usize,
        lone: bool,
        load: impl Fn(usize) -> Result<N, NetworkError>,
    ) -> Result<Self, NetworkError> {
        let workers = workers.max(1);
        Ok(Self {
            lone: if lone && workers > 1 {
                Some(std::sync::Mutex::new(load(workers)?))
            } else {
                None
            },
            workers: (0..workers)
                .map(|_| load(1).map(std::sync::Mutex::new))
                .collect::<Result<Vec<_>, _>>()?,
        })
    }

    /// One compiled model, for every run.
    pub fn one(model: N) -> Self {
        Self {
            workers: vec![std::sync::Mutex::new(model)],
            lone: None,
        }
    }

    /// Locks the compiled model of `worker` (any number: taken modulo their count);
    /// `None`: the lone run's (the first worker's without one).
    pub fn lock(
        &self,
        worker: Option<usize>,
    ) -> Result<std::sync::MutexGuard<'_, N>, NetworkError> {
        let net = match (worker, &self.lone) {
            (None, Some(lone)) => lone,
            (w, _) => self
                .workers
                .get(w.unwrap_or(0) % self.workers.len().max(1))
                .ok_or_else(|| error("running the model", "no compiled model"))?,
        };
        net.lock()
            .map_err(|_| error("running the model", "a previous run panicked"))
    }
}

impl CompiledModels<LiteRtNetwork> {
    /// Runs every compiled model once on zeros (`input_floats` of them): XNNPACK packs
    /// its weights at a model's first run, which would otherwise fall on a frame.
    pub fn warm_up(&self, input_floats: usize) -> Result<(), NetworkError> {
        let zeros = vec![0.0; input_floats];
        for model in self.workers.iter().chain(&self.lone) {
            model
                .lock()
                .map_err(|_| error("warming up", "a previous run panicked"))?
                .run_raw(&zeros)?;
        }
        Ok(())
    }
}

/// The landmark model on its runtime.
pub enum Landmarks {
    /// tract: one optimised plan, run by any number of threads at once.
    Tract(super::landmarks::LandmarkNetwork),
    /// LiteRT: compiled for parallel runs and a frame's lone run (one person followed).
    LiteRt(CompiledModels),
}

impl Landmarks {
    /// The original landmark model at `path` compiled by LiteRT, once per worker and
    /// once on `workers` threads.
    pub fn litert(runtime: &LiteRt, path: &Path, workers: usize) -> Result<Self, NetworkError> {
        Ok(Self::LiteRt(CompiledModels::load(
            workers,
            true,
            |threads| LiteRtNetwork::load(runtime, path, threads),
        )?))
    }

    /// Runs every compiled model (tract: the plan) once on zeros, before the first
    /// frame.
    pub fn warm_up(&self) -> Result<(), NetworkError> {
        let floats = super::landmarks::INPUT_SIZE * super::landmarks::INPUT_SIZE * 3;
        match self {
            Self::Tract(network) => network.run(&vec![0.0; floats]).map(drop),
            Self::LiteRt(models) => models.warm_up(floats),
        }
    }

    /// Runs on one crop (`256 x 256 x 3`, values in [0, 1]); `worker` picks LiteRT's
    /// compiled model (any number: taken modulo their count), `None`: the lone run's
    /// (on all the workers' cores).
    pub fn run(&self, worker: Option<usize>, rgb: &[f32]) -> Result<LandmarkOutput, NetworkError> {
        match self {
            Self::Tract(n) => n.run(rgb),
            Self::LiteRt(models) => models.lock(worker)?.run(rgb),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Compiled models standing for LiteRT's: the threads each was made for and which.
    fn models(workers: usize, lone: bool) -> CompiledModels<(usize, usize)> {
        let made = std::cell::Cell::new(0);
        CompiledModels::load(workers, lone, |threads| {
            made.set(made.get() + 1);
            Ok((threads, made.get()))
        })
        .expect("loads")
    }

    #[test]
    fn a_lone_run_gets_the_model_on_every_workers_core_and_a_worker_its_own() {
        let m = models(3, true);
        // The lone model first, on 3 threads; then one per worker, on 1 each.
        assert_eq!(*m.lock(None).expect("lone"), (3, 1));
        assert_eq!(*m.lock(Some(0)).expect("worker 0"), (1, 2));
        assert_eq!(*m.lock(Some(2)).expect("worker 2"), (1, 4));
        // Any worker number, modulo their count.
        assert_eq!(*m.lock(Some(5)).expect("worker 5"), (1, 4));
        // Without a lone model (not asked for, or one worker): the first worker's.
        assert_eq!(*models(3, false).lock(None).expect("none"), (1, 1));
        let one = models(1, true);
        assert_eq!(*one.lock(None).expect("one"), (1, 1));
        assert_eq!(*one.lock(Some(7)).expect("any"), (1, 1));
    }
}
