#pragma once
/// @file Registration of ultrasound frames to a volume: analytic pose
/// gradients of slice-to-frame similarity metrics, fused in one pass over the pixels (no image
/// is materialised), and Gauss–Newton / Levenberg–Marquardt pose optimisation with multi-start
/// and a coarse-to-fine schedule. docs/registration.md has the formulas.
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "sonoslice/core/Error.h"
#include "sonoslice/geometry/Pose.h"
#include "sonoslice/geometry/Probe.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {

enum class RegistrationMetric {
  SSD,  ///< mean squared difference (frame and volume on the same intensity scale)
  NCC,  ///< normalised cross-correlation (any linear intensity relation); cost 1 − NCC
  /// Local NCC: the mean of the NCCs of the fan's patches (11 full-resolution pixels a side);
  /// cost 1 − LNCC. Derivative-free optimisers only.
  LNCC,
  /// Mutual information of a 32 × 32 joint histogram, each sample split over its 2 × 2 nearest
  /// bins (Parzen, linear kernel: continuous in the pose), intensities clipped to the volume's
  /// and each frame's 1st–99th percentiles; cost −MI (nats). Derivative-free optimisers only.
  MI,
  /// Wein et al. 2008's linear correlation of linear combination, for ultrasound against CT:
  /// in each patch the frame is fitted by the volume's intensity and its gradient magnitude
  /// along the beam; LC2 is the patches' R² weighted by the frame's local standard deviation;
  /// cost 1 − LC2. No analytic derivatives: BOBYQA or Nelder–Mead.
  LC2
};
enum class RegistrationOptimizer {
  GaussNewton,
  LevenbergMarquardt,
  Bobyqa,     ///< derivative-free (NLopt's LN_BOBYQA); needs a build with NLopt
  NelderMead  ///< derivative-free (NLopt's LN_NELDERMEAD); needs a build with NLopt
};
/// True when this build has NLopt (the derivative-free optimisers).
bool built_with_nlopt();
enum class RegistrationMode {
  PerFrame,    ///< each frame's pose refined on its own (6 DoF each)
  RigidSweep,  ///< one world-frame correction X shared by all frames: refined poses X · T_i
  /// Per-frame corrections X_i with a smoothness prior along the sweep (frames in sweep order):
  /// the rigid-sweep correction first, then Gauss–Newton / LM on all frames jointly, the cost
  /// Σ cost_i + Σ_i (d_{i+1} − d_i)ᵀ·W·(d_{i+1} − d_i), d_i the correction of frame i's centre
  /// (mm) and its rotation vector. SSD and NCC only. docs/registration.md §5.
  SmoothSweep,
  /// One probe-side correction X shared by all frames: refined poses T_i · X, the error of the
  /// probe calibration (PLUS's ImageToProbe) rather than of the tracker-to-volume registration.
  Calibration
};

/// Every value of each choice, in the order of its spelling table (the parsers and the Python
/// enums take them from here).
inline constexpr RegistrationMetric kRegistrationMetrics[] = {
    RegistrationMetric::SSD, RegistrationMetric::NCC, RegistrationMetric::LNCC,
    RegistrationMetric::MI, RegistrationMetric::LC2};
inline constexpr RegistrationOptimizer kRegistrationOptimizers[] = {
    RegistrationOptimizer::GaussNewton, RegistrationOptimizer::LevenbergMarquardt,
    RegistrationOptimizer::Bobyqa, RegistrationOptimizer::NelderMead};
inline constexpr RegistrationMode kRegistrationModes[] = {
    RegistrationMode::PerFrame, RegistrationMode::RigidSweep, RegistrationMode::SmoothSweep,
    RegistrationMode::Calibration};

/// The spelling tables (the CLI's flag values, Python's strings): "ssd", "ncc", "lncc", "mi",
/// "lc2"; "gn", "lm", "bobyqa", "nelder-mead"; "per-frame", "rigid-sweep", "smooth-sweep",
/// "calibration".
/// The parsers throw InputError "<what> <name>: expected ..." (`what`: the setting as the caller
/// spells it).
RegistrationMetric parse_registration_metric(const std::string& name,
                                             const std::string& what = "metric");
RegistrationOptimizer parse_registration_optimizer(const std::string& name,
                                                   const std::string& what = "optimizer");
RegistrationMode parse_registration_mode(const std::string& name, const std::string& what = "mode");
const char* to_string(RegistrationMetric metric);
const char* to_string(RegistrationOptimizer optimizer);
const char* to_string(RegistrationMode mode);
/// True for the metrics with analytic derivatives (SSD, NCC): the ones GN and LM can optimise.
bool metric_has_derivatives(RegistrationMetric metric);
/// The optimiser a metric gets when none is asked for: Levenberg–Marquardt for the metrics with
/// derivatives (ssd, ncc), BOBYQA for the others (lncc, mi, lc2).
RegistrationOptimizer default_optimizer(RegistrationMetric metric);
/// The pyramid a metric gets when none is asked for: 8, 4, 2, 1 for ssd, ncc, lncc and mi; 2, 1
/// for lc2, whose coarser levels pull B-mode frames away from their optimum (measured in
/// docs/registration.md §5).
std::vector<int> default_pyramid(RegistrationMetric metric);
/// The most automatic starts a frame gets (RegistrationSettings::starts unset; a correction
/// shared by a sweep gets kAutoMaxSweepStarts): kAutoMaxStartsWithDerivatives for ssd and ncc,
/// kAutoMaxStarts for the others.
int default_max_starts(RegistrationMetric metric);

/// What a registration does. Every default is here, once: `sonoslice register` and Python's
/// `register` set only what their user gave.
struct RegistrationSettings {
  RegistrationMetric metric = RegistrationMetric::NCC;
  /// Unset: default_optimizer(metric) (resolved()).
  std::optional<RegistrationOptimizer> optimizer;
  RegistrationMode mode = RegistrationMode::PerFrame;
  /// Optimisations per frame (per sweep in the sweep modes), each from one of the best-ranked
  /// of many points drawn around the initial pose (the initial pose among them; rotation up to
  /// search_rot_deg about a random axis through the frame's centre, translation uniform in a
  /// ball of search_trans_mm); the best end wins. Unset (the default): automatic, one start after
  /// another until the best end has been reached from kAgreeingStarts starts (kAgreementMm
  /// and kAgreementDeg apart at most), at most kAutoMaxStarts; in the sweep modes and
  /// calibration mode at most kAutoMaxSweepStarts. Automatic starts run the pyramid's finest
  /// level only from coarse ends that are the best so far or near one that ran it
  /// (docs/registration.md §3). A number: exactly that many, each through every level.
  std::optional<int> starts;
  double search_rot_deg = 10, search_trans_mm = 10;
  uint64_t seed = 0;  ///< the multi-start draws
  /// smooth-sweep: the prior's weight W relative to the frames' own curvature. At each pyramid
  /// level W = smoothness × the frames' mean Gauss–Newton diagonal (translation and rotation
  /// apart), so 1 means a 1 mm step between neighbouring corrections costs about what moving a
  /// typical frame 1 mm off its own optimum does; 0 is per-frame registration from the
  /// rigid-sweep result. The default 0.3 was the best of 0–100 on the test's noisy sweep.
  /// Unset: kDefaultSmoothness in smooth-sweep mode (resolved()); set in another mode it would
  /// change nothing, so validate() refuses it.
  std::optional<double> smoothness;
  static constexpr double kDefaultSmoothness = 0.3;
  /// Coarse to fine: at level k the volume is averaged over blocks of pyramid[k]³ voxels and
  /// the frame over blocks of pyramid[k]² pixels, of which one pixel per block is compared.
  /// Unset: default_pyramid(metric) (resolved()).
  std::optional<std::vector<int>> pyramid;
  int max_iterations = 50;  ///< per level
  /// Converged when a step moves the frame's centre less than this (mm) and turns it less than
  /// tolerance_deg.
  double tolerance_mm = 1e-3, tolerance_deg = 1e-3;

  /// These settings with the defaults chosen: the optimizer and the pyramid set.
  RegistrationSettings resolved() const;
  /// Throws InputError naming the setting (as `names` spells it) for starts < 1, negative or
  /// non-finite spreads, an empty pyramid or a level outside 1..64, max_iterations < 1,
  /// non-positive tolerances, a metric without derivatives with a derivative-based optimiser or
  /// in smooth-sweep mode, a negative or non-finite smoothness, and a derivative-free
  /// optimiser in a build without NLopt.
  void validate(const ParameterNames& names = {}) const;
};

/// Starts that must reach the best end for a frame (a sweep) to be called converged, and for
/// automatic starts to stop. Two starts sometimes agree on a wrong pose (a local minimum with a
/// wide basin, or a symmetric structure): on 40 CT fans 10 mm and 10° off, two agreeing starts
/// called 4 of 10 misses converged, three 1 of 8; on 40 sweeps, two once agreed on a local
/// minimum that a later start would have left.
constexpr int kAgreeingStarts = 3;
/// Automatic starts (RegistrationSettings::starts unset) for the metrics without derivatives
/// (lncc, mi, lc2): at most this many. On simulated B-mode frames LC2 with at most 48 recovered
/// more from 5 mm (30 % against 15 %) but took 2.5 s a frame instead of 0.9, and called three
/// misses converged instead of none (docs/registration.md §5).
constexpr int kAutoMaxStarts = 12;
/// Automatic starts for ssd and ncc: at most this many. A Levenberg–Marquardt start costs little,
/// and frames that need many starts are the ones far off: on 80 CT fans 10 mm and 10° off, at
/// most 12, 24, 48 and 96 starts brought 81, 89, 95 and 99 % to within 1 mm and 1°, in 0.21,
/// 0.32, 0.38 and 0.67 s a frame, with 1, 1, 1 and 0 misses called converged.
constexpr int kAutoMaxStartsWithDerivatives = 48;
/// Automatic starts for one correction shared by a whole sweep (rigid-sweep, smooth-sweep's
/// first stage, calibration): at most this many. One wrong sweep moves every frame, and a
/// sweep's optimisation costs about as much as its frames' would, so it may try more.
constexpr int kAutoMaxSweepStarts = 16;
/// Two optimisations reached the same end when their results move the frame's (or the sweep's)
/// centre at most this far apart and turn at most this much apart.
constexpr double kAgreementMm = 1, kAgreementDeg = 1;
/// A sweep in rigid-sweep or calibration mode (not smooth-sweep, whose frames need not share one
/// correction) of at least 4 frames with contrast is converged only when its first and second
/// halves, each refined alone from the sweep's correction (one start, full resolution), end at most
/// this far apart at every frame's centre, and so, for a sweep that moves more within its image
/// plane than through it (whose frames' halves see the same tissue), do the left and right halves
/// of its frames' pixels. Agreeing starts cannot catch a wrong optimum that every start reaches;
/// the halves see other tissue and usually pull apart there. The bound is the accuracy a sweep is
/// judged by in docs/registration.md §5: there the recovered sweeps' halves ended at most 0.26 mm
/// apart (49 MI B-mode sweeps on the liver's surface; 0.36 mm for LC2's 11) and 0.01 mm (39 CT
/// sweeps), their sides at most 0.28 mm (17 MI sweeps across), while MI's misses that three
/// starts had agreed on ended 0.88–24 mm apart (halves, through the plane) and 0.52–1.88 mm
/// (sides, across).
constexpr double kHalvesAgreementMm = 0.5;

/// One frame's outcome (JSON report fields, docs/registration.md §4). In the sweep modes the
/// starts, agreement and convergence are the sweep's.
struct FrameReport {
  size_t index = 0;
  double metric = 0;  ///< the final cost at full resolution (SSD, or 1 − NCC)
  int64_t evaluations = 0, iterations = 0;
  double translation_change_mm = 0, rotation_change_deg = 0;  ///< refined against initial
  int starts = 0;                                             ///< optimisations run
  int agreeing_starts = 0;  ///< of them, those that ended at the best end (itself included)
  /// The best end was reached from at least kAgreeingStarts starts and its cost is finite (and,
  /// in rigid-sweep and calibration mode, the sweep's halves agree: kHalvesAgreementMm). One
  /// optimisation alone cannot tell its optimum from a local minimum, and two sometimes agree on a
  /// wrong one, so fewer starts are never converged.
  bool converged = false;
  /// The result's standard deviation (ssd and ncc; NaN for the other metrics): of the frame's
  /// (the sweep's) centre, mm, and of its rotation, degrees, each the root of the trace of its
  /// block of the covariance (2·cost/n)·H⁻¹ (H the Gauss–Newton matrix at the result, n the
  /// pixels compared): what independent pixel noise of the residual's size would leave. A
  /// direction the frame does not constrain (a homogeneous organ, a symmetric structure) shows
  /// as a large value. Correlated noise (speckle) makes the true spread larger.
  double uncertainty_mm = std::numeric_limits<double>::quiet_NaN();
  double uncertainty_deg = std::numeric_limits<double>::quiet_NaN();
  /// The share of the other starts that confirmed the best end: (agreeing_starts − 1) /
  /// (starts − 1), 0 with a single start (0 to 1).
  double confidence() const {
    return starts > 1 ? double(agreeing_starts - 1) / double(starts - 1) : 0.0;
  }
};

struct RegistrationReport {
  RegistrationSettings settings;  ///< what ran: the caller's settings, resolved()
  std::vector<FrameReport> frames;
  /// The shared correction: rigid-sweep's and smooth-sweep's first stage X (world side, refined
  /// poses X · T_i), calibration's X (probe side, T_i · X); unset per frame.
  std::optional<Pose> correction;
  /// The sweep's own cost at the shared correction, full resolution: the cost the sweep modes and
  /// calibration minimise (all frames' pixels or patches together; MI the mean of the frames');
  /// for smooth-sweep, its rigid first stage's. Unset per frame and for a sweep without contrast.
  std::optional<double> sweep_metric;
  /// The sweep's halves check (kHalvesAgreementMm): how far apart (mm, the largest over the
  /// frames' centres) the corrections of its first and second halves, each refined alone from
  /// the shared correction, end. Unset per frame, in smooth-sweep mode and for sweeps of fewer
  /// than 4 frames with contrast.
  std::optional<double> halves_mm;
  /// The same for the left and right halves of the frames' pixels (either side of the compared
  /// pixels' median column), each side refined alone over the frames with contrast on both
  /// sides. Unset where halves_mm is, and where fewer than 4 frames have contrast on both sides.
  std::optional<double> sides_mm;
  int64_t evaluations = 0;
  double seconds = 0;
};

/// The metric's sums at one pose over the pixels of one frame, and their derivatives with
/// respect to a world-frame increment ξ = (v, ω) of the pose about a centre c:
/// T(ξ) = Tr(c)·exp(ξ)·Tr(−c)·T, i.e. a pixel's world point w moves by v + ω × (w − c).
/// J = dI/dξ = (∇I, (w − c) × ∇I) per pixel, with ∇I the trilinear gradient in world mm.
struct PoseTerms {
  double n = 0;  ///< pixels compared (inside the masks and volume)
  double si = 0, sf = 0, sii = 0, sff = 0, sif = 0;  ///< Σ I, Σ F, Σ I², Σ F², Σ I·F
  double sj[6] = {}, sij[6] = {}, sfj[6] = {};       ///< Σ J, Σ I·J, Σ F·J
  double sjj[21] = {};                               ///< Σ J·Jᵀ, upper triangle row by row
  void add(const PoseTerms& other);
};

/// The cost (SSD: Σ(I − F)²/n; NCC: 1 − ρ), its gradient and a Gauss–Newton matrix (6×6,
/// row-major) from the terms; cost is +inf with fewer than 16 pixels.
double metric_cost(RegistrationMetric metric, const PoseTerms& t, double* gradient = nullptr,
                   double* hessian = nullptr);

/// Applies the increment ξ = (v, ω) about centre c to pose T: Tr(c)·exp(ξ)·Tr(−c)·T.
Pose apply_increment(const Pose& pose, const double xi[6], const Vec3& centre);

/// Bound to one volume (read as float, shared when float32), one probe, a stack of frames
/// (count × H × W floats, the probe's grid) and an optional H×W user mask (non-zero: compare).
class FrameRegistration {
 public:
  FrameRegistration(const Volume& volume, const ProbeGeometry& probe, const float* frames,
                    size_t frame_count, const uint8_t* user_mask = nullptr);
  ~FrameRegistration();

  /// Makes pyramid level `level` (a block size, 1..64) unless it exists: terms(), patch_score(),
  /// mutual_information() and cost() read prepared levels only (InputError otherwise); level 1
  /// is made by the constructor, run() makes its settings' pyramid. Not to be called while
  /// another thread evaluates.
  void prepare_level(int level) const;

  /// The terms of frame `frame` at `pose` at pyramid level `level` (a block size of the
  /// settings' pyramid; 1: every pixel of the full-resolution volume), with their derivatives
  /// about `centre` when `gradients`.
  PoseTerms terms(size_t frame, const Pose& pose, int level, const Vec3& centre,
                  bool gradients) const;
  /// The patch metrics of frame `frame` at `pose` at pyramid level `level`, as two sums over
  /// the patches: LC2: Σ σ_U·R² and Σ σ_U; LNCC: Σ NCC and the patch count (the metric is the
  /// first over the second; both 0 without a usable patch).
  std::pair<double, double> patch_score(size_t frame, const Pose& pose, int level,
                                        RegistrationMetric metric) const;
  /// The mutual information (nats) of frame `frame` and the volume at `pose`, level `level`;
  /// NaN with fewer than 16 samples.
  double mutual_information(size_t frame, const Pose& pose, int level) const;
  /// The cost of `metric` (SSD, 1 − NCC, 1 − LNCC, −MI or 1 − LC2) for frame `frame` at
  /// `pose`, level `level`.
  double cost(size_t frame, const Pose& pose, int level, RegistrationMetric metric) const;
  /// The world point of the centre of frame `frame`'s compared pixels at `pose`.
  Vec3 centre(size_t frame, const Pose& pose) const;

  /// Refines the initial poses (one per frame; InputError naming "pose <i>" for a bad one) with
  /// settings.resolved() and reports. Frames are optimised in parallel, each on one thread: the
  /// result does not depend on the thread count. Warns (warn(), one line) when any frame is not
  /// converged.
  std::vector<Pose> run(const std::vector<Pose>& initial, const RegistrationSettings& settings,
                        RegistrationReport* report) const;

 private:
  struct State;
  std::unique_ptr<State> state_;
};

}  // namespace sonoslice
