//! The solver's options, shared by `lift` and `parity`.

use clap::Args;
use posestream::solver::coefficients::CoefficientSolver;
use posestream::{InitMethod, Params};

/// The estimator's parameters as options (defaults: [`Params::default`]).
#[derive(Debug, Args)]
pub struct SolverArgs {
    /// L1 weight on the coefficients.
    #[arg(long, default_value_t = Params::default().alpha)]
    alpha: f64,
    /// Temporal smoothness of the coefficients.
    #[arg(long, default_value_t = Params::default().beta)]
    beta: f64,
    /// Temporal smoothness of the rotations.
    #[arg(long, default_value_t = Params::default().gamma)]
    gamma: f64,
    /// E-step Gaussian std (normalised units; a heat map is 6 units high).
    #[arg(long, default_value_t = Params::default().sigma)]
    sigma: f64,
    /// Turn temporal smoothness off (beta = gamma = 0).
    #[arg(long)]
    no_smooth: bool,
    /// Initialisation: convex+robust+refine, convex+refine or altern [default: convex+robust+refine
    /// for keypoints, altern for heat maps].
    #[arg(long)]
    init: Option<InitMethod>,
    /// C-step solver: active-set (Newton steps on the active coefficients), cd
    /// (coordinate descent) or apg (accelerated proximal gradient, the paper's).
    #[arg(long, default_value = "active-set")]
    c_solver: CoefficientSolver,
    /// Outlier threshold of the robust convex initialisation (normalised units).
    #[arg(long, default_value_t = Params::default().robust_threshold)]
    robust_threshold: f64,
    /// Heat-map joints whose peak is not above this are left out of the initialisation.
    #[arg(long, default_value_t = Params::default().visibility_threshold)]
    visibility_threshold: f64,
    /// EM iterations at most.
    #[arg(long, default_value_t = Params::default().max_em_iterations)]
    max_em_iterations: usize,
    /// Block-coordinate rounds of Algorithm 1 on keypoints at most.
    #[arg(long, default_value_t = Params::default().max_rounds)]
    max_rounds: usize,
    /// Block-coordinate rounds per EM M-step at most (heat maps).
    #[arg(long, default_value_t = Params::default().max_em_rounds)]
    max_em_rounds: usize,
    /// APG steps (or CD sweeps) per C-step at most.
    #[arg(long, default_value_t = Params::default().max_apg_steps)]
    max_apg_steps: usize,
    /// Newton steps of the active-set C-step per round at most.
    #[arg(long, default_value_t = Params::default().max_newton_steps)]
    max_newton_steps: usize,
    /// Newton sweeps per R-step at most.
    #[arg(long, default_value_t = Params::default().max_rotation_sweeps)]
    max_rotation_sweeps: usize,
    /// Iterations of the per-frame initialisation at most.
    #[arg(long, default_value_t = Params::default().max_init_iterations)]
    max_init_iterations: usize,
    /// Relative tolerance of the stopping rules.
    #[arg(long, default_value_t = Params::default().tolerance)]
    tolerance: f64,
    /// The paper's model, as the authors' release runs it: no fitting of the person's
    /// shape beyond the dictionary, every joint weighing 1 in the EM, no left/right swap
    /// hypothesis in the E-step, the EM from each frame's own initialisation instead of
    /// a sliding window's pass (`posestream parity` runs it whatever this says).
    #[arg(long)]
    paper: bool,
}

impl SolverArgs {
    /// The parameters these options give.
    pub fn params(&self) -> Params {
        let p = Params {
            alpha: self.alpha,
            beta: self.beta,
            gamma: self.gamma,
            sigma: self.sigma,
            robust_threshold: self.robust_threshold,
            visibility_threshold: self.visibility_threshold,
            max_em_iterations: self.max_em_iterations,
            max_rounds: self.max_rounds,
            max_em_rounds: self.max_em_rounds,
            max_apg_steps: self.max_apg_steps,
            max_newton_steps: self.max_newton_steps,
            max_rotation_sweeps: self.max_rotation_sweeps,
            max_init_iterations: self.max_init_iterations,
            tolerance: self.tolerance,
            init: self.init,
            coefficient_solver: self.c_solver,
            ..if self.paper {
                Params::reference()
            } else {
                Params::default()
            }
        };
        if self.no_smooth {
            p.without_smoothness()
        } else {
            p
        }
    }
}
