//! Honest variances for quasi-Monte Carlo rays ([`Sampler::Qmc`](crate::Sampler)).
//!
//! The estimators' variances (`sum x²` of shooting's deposits, `s² / n` of a gathering's or the
//! direct light's samples) assume independent rays. A patch's quasi-Monte Carlo rays are
//! stratified, negatively correlated, so its true variance is lower by a factor `g < 1` (the
//! *gain*) that depends on the scene and the patch: measured 0.56-0.82 for shooting and
//! 0.12-0.32 for the gathered direct light (issue 17), so the formula alone overstates the
//! error and gives the combination's weights a wrong balance.
//!
//! Every sequence interleaves two independent randomisations ([`mcrad_random::REPLICATES`]):
//! the even and the odd rays of a patch are two independent estimates of the same thing, and
//! their difference measures the error of the stratified rays:
//!
//! - for a mean of `n = n_0 + n_1` samples, `(m_0 - m_1)² n_0 n_1 / n²` is unbiased for the
//!   variance of the mean (`(m_0 - m_1)² / 4` for equal halves);
//! - for a sum (shooting's deposits on a patch), `(S_0 - S_1)²` is unbiased for the variance of
//!   `S_0 + S_1`.
//!
//! One patch's difference has one degree of freedom: far too noisy to use alone (a weight that
//! follows the estimate's own luck biases the combination). So the replicates only measure the
//! gain, pooled over the patches of an input face (which see nearly the same scene through the
//! same kind of rays), drawn towards 1 (the independent-ray formula) with the weight of
//! [`PRIOR_PATCHES`] patches:
//!
//! ```text
//! g_f = (sum_{i in f} q_i + c m_f) / (sum_{i in f} v_i + c m_f)
//! ```
//!
//! with `q_i` the replicate estimate and `v_i` the independent-ray formula of patch `i` (summed
//! over the channels), `m_f` the face's mean `v`, `c` = [`PRIOR_PATCHES`]. The reported variance
//! is `g_f v_i`: the formula's shape over the patches, the face's measured scale. A face of
//! many patches (a subdivided wall: the default meshes) gets its own gain; a face of one patch
//! stays near the formula, which overstates the error of stratified rays rather than
//! understating it. (Drawing towards the gain over the whole scene was tried: that gain is the
//! brightest patches', lit straight from the emitters' sequences, where stratification pays
//! most; on the Cornell box of one patch per face it made the dimmer walls' variances 1.7x too
//! small, mean `z²` 2.6 against the reference.) Under independent rays the gain would be 1 on
//! average, so [`Sampler::Random`](crate::Sampler) keeps the formula as it is (exactly 1).
//!
//! **Shooting measures more.** A shooting run's waves are independent given the waves before
//! them, so each wave's even-odd difference is one more degree of freedom ([`Waves`]): a patch
//! lit over many bounces measures its own gain with tens of them, and shooting's faces are
//! drawn towards the gain of faces that received about as many deposits rather than the
//! formula ([`Toward::Alike`]). A face of one
//! patch (`--no-subdivide`) then reports its stratified error: in a closed furnace of one
//! patch per face at rho 0.9 and 0.99 (`cargo xtask calibrate`, cases `furnace-*-faces`), the
//! gain is a few percent, and `prr`'s spread between seeds over its reported variance went
//! from 0.04 to 0.8-1.0. Gathering and the direct light run one round per call: their
//! patches keep one difference each, drawn towards the formula as above.
//!
//! The waves' differences are scaled by the share of their variance the whole run keeps
//! (`kappa`, [`Waves::gains`]), measured per pair of source and receiver patch, and by what
//! the later waves make of a wave's error ([`Waves::carry_factor`], where it lowers it):
//! measured per receiver alone, with 5 degrees of freedom in a furnace of one patch per face,
//! and without the carrying, `shoot` there reported 2.5x its spread (issue 36, item 2).
//!
//! **Where a patch casts few rays a wave** (the late waves at high reflectance, the
//! finishing roulette; `combined`'s passes cast under a ray a patch a wave on a furnace of one
//! patch per face) three things keep the samples true (issue 36): the error a patch carries
//! on is spread over where its last [`RECENT`] rays went, not put whole on one patch
//! ([`Waves::ray`]); a ray alone in its replicate is paired with the patch's next lone ray of
//! the other replicate into an error sample ([`LoneRays`]); and the error left pending at the
//! run's end, on patches that will not shoot again, gets its future as the roulette's
//! correction gives the dropped power its own (`crate::shoot`), so that the samples' total
//! over a closed scene is as exact as shooting's. Measured against the exact answer
//! (`combined`, 2e5 rays, sums over the patches): the samples held 1.18 times the shooting's
//! squared error on that furnace (64 seeds) and 0.61 times on the subdivided rho 0.9 one (16
//! seeds) before, 0.99 times on the latter after.
//!
//! **`combined` measures its gathers' own noise over its passes.** Each pass gathers once
//! with independent streams, so every pass gives each patch one more signed difference
//! ([`Halves::error_of_mean`]) of its indirect gathering and one of its direct light; their
//! squares, merged over the passes as the gathers are, measure the gathers' own variance
//! without the formula's pull (`crate::schedule::combined`): a face of one patch in a
//! small-light room reported 7x its spread before. The other methods that gather from a
//! shooting (`two-pass`, `two-pass-split`, `progressive-gather`, `progressive-two-pass`)
//! measure theirs the same way over their rounds (`crate::schedule::samples`), a face's
//! measure drawn towards the scene's where the rounds are few (`two-pass` has one).

use glam::{DVec3, Vec3};

/// Error samples per patch kept by shooting ([`Waves::sketch`]): the waves are dealt round robin
/// into this many groups, each group's summed replicate differences one sample of the run's
/// error over every patch at once.
pub(crate) const SKETCHES: usize = 8;

/// One patch's [`SKETCHES`] error samples (per channel; W or W/m² as the holder says), in
/// `f32`: a sample needs the precision of a variance estimate with [`SKETCHES`] degrees of
/// freedom (a few per cent), not that of the radiosity, and they are most of the memory the
/// error samples cost (issue 36). The sums they come from are short (one wave's deposits on
/// one patch; one job's gathering rays).
/// Flat, sample `g`'s channel `c` at `3 g + c` ([`sample`]): the hot loops add whole rows
/// (a ray's carried error, a gathering ray's hit), which then compile to a few vector adds.
pub(crate) type Row = [f32; 3 * SKETCHES];

/// A row of zeros.
pub(crate) const ZERO_ROW: Row = [0.0; 3 * SKETCHES];

/// How many of a patch's last rays carry its error on when it casts fewer than this in a
/// wave ([`Waves::ray`]). The error carried on should be `K d`, `K` the transport's
/// expectation; the rays that carry it sample `K` with noise of their own, which the later
/// waves' differences already hold. A patch casting a ray or two a wave (the late waves of a
/// run at high reflectance, the finishing roulette) carried its whole error to one patch and
/// added that noise again at full size (`combined` on a furnace of one patch per face at rho
/// 0.99: its shooting's samples held 1.18 times its error, the gain-calibrated variance 1.44
/// times, issue 36); spread over where its last [`RECENT`] rays went, it adds about
/// `1 / RECENT` of it, still at once. (Spreading it over the patch's next rays instead, each
/// taking a share of what is left, removed the noise as well but delayed the carrying.)
pub(crate) const RECENT: usize = 16;

/// A ring slot of [`Waves::ray`] not yet filled.
const EMPTY: u32 = u32::MAX;
/// A ring slot of a ray that kept nothing (it escaped or hit a back face).
const NOTHING: u32 = u32::MAX - 1;

/// Sample `g` of `row`, per channel.
#[inline]
pub(crate) fn sample(row: &Row, g: usize) -> DVec3 {
    DVec3::new(
        f64::from(row[3 * g]),
        f64::from(row[3 * g + 1]),
        f64::from(row[3 * g + 2]),
    )
}

/// Adds `x` to sample `g` of `row`.
#[inline]
pub(crate) fn add_sample(row: &mut Row, g: usize, x: DVec3) {
    row[3 * g] += x.x as f32;
    row[3 * g + 1] += x.y as f32;
    row[3 * g + 2] += x.z as f32;
}

/// `a += b`, sample by sample.
#[inline]
pub(crate) fn add_row(a: &mut Row, b: &Row) {
    for (a, b) in a.iter_mut().zip(b) {
        *a += *b;
    }
}

/// `a += rho b`, `rho` per channel (the same for every sample).
#[inline]
pub(crate) fn add_row_scaled(a: &mut Row, b: &Row, rho: Vec3) {
    let r: Row = std::array::from_fn(|k| rho[k % 3]);
    for ((a, b), r) in a.iter_mut().zip(b).zip(&r) {
        *a += *b * *r;
    }
}

/// `rho row`, `rho` per channel.
#[inline]
pub(crate) fn scaled(row: &Row, rho: Vec3) -> Row {
    std::array::from_fn(|k| row[k] * rho[k % 3])
}

/// The weight, in patches, of the independent-ray formula (gain 1) in a face's gain
/// ([module](self)).
pub(crate) const PRIOR_PATCHES: f64 = 4.0;

/// The sums of one patch's values split by replicate (even and odd rays of its sequence). The
/// rays alternate between the replicates, so of `n` rays `ceil(n / 2)` are even and
/// `floor(n / 2)` odd: the counts are the caller's `n`, not stored.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Halves {
    /// Sum of the values per replicate.
    pub sum: [DVec3; 2],
}

impl Halves {
    /// Adds a value of replicate `r`.
    #[inline]
    pub fn push(&mut self, r: usize, x: DVec3) {
        self.sum[r] += x;
    }

    /// Both sets of sums together.
    pub fn merge(self, other: Halves) -> Halves {
        Halves {
            sum: [self.sum[0] + other.sum[0], self.sum[1] + other.sum[1]],
        }
    }

    /// The replicates' estimate of the variance of the mean of all `n` samples,
    /// `(m_0 - m_1)² n_0 n_1 / n²` summed over the channels; `None` below two samples.
    pub fn variance_of_mean(&self, n: u64) -> Option<f64> {
        let (n0, n1) = (n.div_ceil(2) as f64, (n / 2) as f64);
        if n1 == 0.0 {
            return None;
        }
        let d = self.sum[0] / n0 - self.sum[1] / n1;
        Some(d.length_squared() * n0 * n1 / (n as f64 * n as f64))
    }

    /// The replicates' signed error sample of the mean of all `n` samples, per channel:
    /// `(m_0 - m_1) sqrt(n_0 n_1) / n`, of mean zero, its square unbiased for the variance of
    /// the mean (one degree of freedom; [`Halves::variance_of_mean`] is its square summed over
    /// the channels). Zero below two samples.
    pub fn error_of_mean(&self, n: u64) -> DVec3 {
        let (n0, n1) = (n.div_ceil(2) as f64, (n / 2) as f64);
        if n1 == 0.0 {
            return DVec3::ZERO;
        }
        (self.sum[0] / n0 - self.sum[1] / n1) * ((n0 * n1).sqrt() / n as f64)
    }

    /// The replicates' estimate of the variance of the sum of all the samples, `(S_0 - S_1)²`
    /// summed over the channels (an empty replicate's sum is 0: a value, not a lack of one).
    pub fn variance_of_sum(&self) -> f64 {
        (self.sum[0] - self.sum[1]).length_squared()
    }
}

/// What one patch (or vertex group) says about its gain.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Measure {
    /// The input face it lies on.
    pub face: u32,
    /// The replicates' estimate of its variance, summed over the channels (`None`: not
    /// measured; the patch then only takes its face's gain).
    pub replicate: Option<f64>,
    /// The independent-ray formula's variance, summed over the channels.
    pub model: f64,
    /// The degrees of freedom of `replicate`: 1 for one difference, more for a sum of
    /// independent differences ([`Waves`]).
    pub dof: f64,
    /// How many values it sums, in effect: `|sum x|² / sum |x|²` over its deposits (equal
    /// deposits: their count), which sets how much stratification can gain
    /// ([`Toward::Alike`]). 0 where not known.
    pub deposits: f64,
}

/// Shooting's replicate differences wave by wave. A wave's even and odd rays are two
/// independent estimates of what the wave deposits given the power it shoots, so the wave's
/// difference `d_w = S_0w - S_1w` has mean zero given the waves before it: the `d_w` are
/// uncorrelated and `E[(sum_w d_w)²] = E[sum_w d_w²]`. The sum of squares measures the same
/// variance as the run's one difference with about `(sum_w v_w)² / sum_w v_w²` degrees of
/// freedom instead of one (Satterthwaite, `v_w` the independent-ray formula of wave `w`):
/// tens for a patch lit over many bounces, so a face of one patch measures its own gain.
/// (The waves' rays continue their patches' sequences, whose stratification across waves the
/// per-wave differences do not see: they may overstate the variance a little, never
/// understate it on that account.)
#[derive(Debug, Clone, Default)]
pub(crate) struct Waves {
    /// This wave's sums of the patches that received a deposit, in the order of their first:
    /// the patch, its sums per replicate and its `sum x²` (channels summed). A wave reaches
    /// at most as many patches as it casts rays: kept sparse, the per-wave sums cost 4 bytes
    /// a patch, not 56.
    wave: Vec<(u32, Halves, f64)>,
    /// Per patch with a row, the run's sums ([`Sums`], 128 bytes): a patch without a deposit
    /// has none, so they are kept with the rows, not per patch (a run of fewer rays than
    /// patches leaves most patches at zero).
    sums: Blocks<Sums>,
    /// Per patch, its entry in the rows `sums`, `sketch`, `pending`, `projected` and `raw`
    /// ([`NO_SLOT`]: no deposit yet, its sums and rows all zero). Rows are made for the
    /// patches that receive a deposit only, in the order of their first: a run of fewer rays
    /// than patches leaves most without (512 bytes each).
    row: Vec<u32>,
    /// Per patch with a row, the differences `d_w` summed over the waves of each group (wave
    /// `w` in group `w mod SKETCHES`), with what the later waves' rays carried there, as far
    /// as the patch's last shot: the rest is in `pending`.
    sketch: Rows,
    /// Waves closed.
    closed: usize,
    /// Per group, the error power the finishing roulette dropped with the unshot power of the
    /// patches it stopped (W per channel; [`Waves::drop_pending`]).
    dropped: [DVec3; SKETCHES],
    /// Per patch with a row, the patches its last [`RECENT`] rays kept power on (its ray `k`
    /// in slot `k mod RECENT`; [`EMPTY`] not yet cast, [`NOTHING`] kept nothing): where a
    /// patch casting few rays in a wave carries its error ([`Waves::ray`]).
    recent: Blocks<[u32; RECENT]>,
    /// Per patch with a row, the error power of each group not yet shot (W per channel): a
    /// deposit's error is power the patch reflects, so it travels on with the patch's next
    /// rays.
    pending: Rows,
    /// Per patch, its entry in `carried` in this wave ([`NO_SLOT`]: its rays carry no error
    /// power; most of all the emitters' first wave, the largest, carries nothing). Dense:
    /// every wave sets it for every patch with a row, in patch order (kept with the rows, it
    /// cost a cache miss a patch a wave).
    carrier: Vec<u32>,
    /// The error power each ray of a carrying patch carries in this wave, in patch order
    /// (sparse as `wave` is: only patches that shoot in the wave carry), and whether the patch
    /// casts fewer than [`RECENT`] rays in it.
    carried: Vec<(Row, bool)>,
    /// Per patch, the input face it lies on ([`Waves::face_scale`]).
    face: Vec<u32>,
    /// Per face, its entry in `face_wave` in this wave ([`NO_SLOT`]: none yet).
    face_slot: Vec<u32>,
    /// This wave's difference `sum_{j in f} d_wj` (W per channel) of the faces it touched, in
    /// the order of their first deposit (sparse as `wave` is).
    face_wave: Vec<(u32, DVec3)>,
    /// Per face, `sum_w |sum_{j in f} d_wj|²`.
    face_differences: Vec<f64>,
    /// Per patch with a row, the run's differences projected over the source patches:
    /// sample `k` is `sum_w sum_i s_ik d_wij` ([`Waves::kappa_by_sources`]), `s_ik = ±1` the
    /// signs of source `i` ([`source_signs`]).
    projected: Rows,
    /// Per patch with a row, the differences `d_w` summed over the waves of each group as in
    /// `sketch`, without what the later waves carried ([`Waves::carry_factor`]).
    raw: Rows,
}

/// The run's sums of one patch with a row ([`Waves::sums`]).
#[derive(Debug, Clone, Copy)]
struct Sums {
    /// Its sums per replicate over the run.
    total: Halves,
    /// `sum_w |d_w|²`.
    differences: f64,
    /// `sum_w v_w` and `sum_w v_w²`.
    model: (f64, f64),
    /// Its entry in `wave` in this wave ([`NO_SLOT`]: no deposit in it yet).
    slot: u32,
    /// The sum of the squares of those deposits (W² per channel).
    squares: DVec3,
    /// The part of `squares` the error samples do not hold (W² per channel): deposits of
    /// rays alone in their replicate ([`LoneRays`]).
    unsampled: DVec3,
}

/// The sums of a patch before its first deposit.
const NO_SUMS: Sums = Sums {
    total: Halves {
        sum: [DVec3::ZERO; 2],
    },
    differences: 0.0,
    model: (0.0, 0.0),
    slot: NO_SLOT,
    squares: DVec3::ZERO,
    unsampled: DVec3::ZERO,
};

/// Rows in blocks of [`ROW_BLOCK`], each made whole and never moved: the store grows without
/// copies, and so without the freed copies a growing array leaves in the allocator's heap
/// (grown an eighth at a time, four arrays of rows held 350 MB more at the peak of a 1M
/// run of 2e7 rays than the arrays they replaced).
#[derive(Debug, Clone)]
struct Blocks<T> {
    blocks: Vec<Vec<T>>,
}

impl<T> Default for Blocks<T> {
    fn default() -> Self {
        Blocks { blocks: Vec::new() }
    }
}

/// Error sample rows in [`Blocks`].
type Rows = Blocks<Row>;

/// Rows in a block of [`Rows`] (384 KiB).
const ROW_BLOCK: usize = 4096;

impl<T> Blocks<T> {
    /// The number of rows.
    fn len(&self) -> usize {
        self.blocks
            .last()
            .map_or(0, |b| (self.blocks.len() - 1) * ROW_BLOCK + b.len())
    }

    /// Appends a row.
    fn push(&mut self, row: T) {
        match self.blocks.last_mut() {
            Some(block) if block.len() < ROW_BLOCK => block.push(row),
            _ => {
                let mut block = Vec::with_capacity(ROW_BLOCK);
                block.push(row);
                self.blocks.push(block);
            }
        }
    }

    /// Row `i` (`i < len`).
    #[inline]
    fn get(&self, i: usize) -> &T {
        &self.blocks[i / ROW_BLOCK][i % ROW_BLOCK]
    }

    /// Row `i` (`i < len`), to change.
    #[inline]
    fn get_mut(&mut self, i: usize) -> &mut T {
        &mut self.blocks[i / ROW_BLOCK][i % ROW_BLOCK]
    }
}

/// The sums of entry `slot` of `sums` (all zero for [`NO_SLOT`]).
#[inline]
fn sums_at(sums: &Blocks<Sums>, slot: u32) -> &Sums {
    match slot {
        NO_SLOT => &NO_SUMS,
        s => sums.get(s as usize),
    }
}

/// The row of entry `slot` of `rows` (all zero for [`NO_SLOT`]).
#[inline]
fn row_at(rows: &Rows, slot: u32) -> &Row {
    match slot {
        NO_SLOT => &ZERO_ROW,
        s => rows.get(s as usize),
    }
}

/// No entry: a patch without a deposit, or without carried error, in this wave ([`Waves`]).
const NO_SLOT: u32 = u32::MAX;

/// The signs `s_ik = ±1` of source patch `i` in the [`SKETCHES`] projections of
/// [`Waves::kappa_by_sources`], per channel (flat as a [`Row`]): a fixed hash of `i`, so the
/// same run gives the same answer.
pub(crate) fn source_signs(i: usize) -> Row {
    let mut z = (i as u64).wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^= z >> 31;
    std::array::from_fn(|k| if (z >> (k / 3)) & 1 == 0 { 1.0 } else { -1.0 })
}

impl Waves {
    /// Sums for the patches of `face` (patch `j` on input face `face[j]`).
    pub fn new(face: Vec<u32>) -> Waves {
        let patches = face.len();
        let faces = face.iter().map(|&f| f as usize + 1).max().unwrap_or(0);
        Waves {
            face,
            face_slot: vec![NO_SLOT; faces],
            face_wave: Vec::new(),
            face_differences: vec![0.0; faces],
            row: vec![NO_SLOT; patches],
            projected: Rows::default(),
            raw: Rows::default(),
            wave: Vec::new(),
            sums: Blocks::default(),
            sketch: Rows::default(),
            closed: 0,
            dropped: [DVec3::ZERO; SKETCHES],
            recent: Blocks::default(),
            pending: Rows::default(),
            carrier: vec![NO_SLOT; patches],
            carried: Vec::new(),
        }
    }

    /// Opens a wave in which patch `i` casts `counts[i]` rays: its pending error power joins
    /// its samples and is spread over them (a patch casting none keeps it, as it keeps its
    /// unshot power).
    pub fn begin_wave(&mut self, counts: &[u64]) {
        self.carried.clear();
        for ((carrier, &row), &n) in self.carrier.iter_mut().zip(&self.row).zip(counts) {
            *carrier = NO_SLOT;
            if row == NO_SLOT {
                continue;
            }
            let (sketch, pending) = (
                self.sketch.get_mut(row as usize),
                self.pending.get_mut(row as usize),
            );
            if n > 0 && *pending != ZERO_ROW {
                let share = 1.0 / n as f32;
                add_row(sketch, pending);
                *carrier = self.carried.len() as u32;
                self.carried
                    .push((pending.map(|z| z * share), n < RECENT as u64));
                *pending = ZERO_ROW;
            }
        }
    }

    /// Ray `k` of patch `i`'s sequence kept power on the front of patch `hit` (`None`: on
    /// none); `rho` gives a patch's reflectance per channel. The error power `i`'s rays carry
    /// in this wave, if any, goes on with it: a share `rho(hit)` of it to `hit`, or, where `i`
    /// casts fewer than [`RECENT`] rays in the wave, to the patches its last [`RECENT`] rays
    /// reached (this one included), each taking its share ([`RECENT`]). It joins their
    /// pending power, and their samples when they next shoot or the run ends.
    #[inline]
    pub fn ray(&mut self, i: usize, k: u64, hit: Option<usize>, rho: impl Fn(usize) -> Vec3) {
        let slots = match self.row[i] {
            NO_SLOT => None,
            s => {
                let slots = self.recent.get_mut(s as usize);
                slots[(k % RECENT as u64) as usize] = hit.map_or(NOTHING, |j| j as u32);
                Some(*slots)
            }
        };
        let (q, few) = match self.carrier[i] {
            NO_SLOT => return,
            s => self.carried[s as usize],
        };
        match slots {
            Some(slots) if few => {
                let filled = slots.iter().filter(|&&j| j != EMPTY).count();
                let share = q.map(|z| z / filled as f32);
                for j in slots.into_iter().filter(|&j| j != EMPTY && j != NOTHING) {
                    let j = j as usize;
                    self.carry_to(&share, j, rho(j));
                }
            }
            _ => {
                if let Some(j) = hit {
                    self.carry_to(&q, j, rho(j));
                }
            }
        }
    }

    /// Error power `q` kept with share `rho` (per channel) on patch `j`: it joins `j`'s
    /// pending power.
    #[inline]
    fn carry_to(&mut self, q: &Row, j: usize, rho: Vec3) {
        let r = self.row_of(j);
        add_row_scaled(self.pending.get_mut(r), q, rho);
    }

    /// Adds an error sample `d` (W per channel) on patch `j` to the current wave's group,
    /// as error power the patch reflects: it joins the patch's pending power, as a wave's
    /// differences do ([`LoneRays`]).
    #[inline]
    pub fn add_error(&mut self, j: usize, d: DVec3) {
        let r = self.row_of(j);
        add_sample(self.pending.get_mut(r), self.closed % SKETCHES, d);
        add_sample(self.raw.get_mut(r), self.closed % SKETCHES, d);
    }

    /// The finishing roulette dropped patch `i`'s unshot power: the error power pending with
    /// it goes too. It stays in the patch's samples (it was deposited there), but the patch
    /// will not shoot it on; the roulette's correction (`crate::shoot`) restores the dropped
    /// power over the scene as the light reflected so far, and with it this error's future:
    /// [`Waves::sketch`] returns the dropped error power per group for the shooting to
    /// spread so.
    pub fn drop_pending(&mut self, i: usize) {
        let slot = self.row[i];
        if slot == NO_SLOT {
            return;
        }
        let pending = std::mem::replace(self.pending.get_mut(slot as usize), ZERO_ROW);
        if pending == ZERO_ROW {
            return;
        }
        add_row(self.sketch.get_mut(slot as usize), &pending);
        for (g, d) in self.dropped.iter_mut().enumerate() {
            *d += sample(&pending, g);
        }
    }

    /// Adds a deposit `x` (W per channel) of replicate `r` on patch `j`, `scale` the factor
    /// `n / (2 n_r)` of the ray's source patch (`n_r` of its `n` rays in the wave of
    /// replicate `r`): the replicates' scaled deposits then have the same mean whatever the
    /// parity of `n`, and their difference is the error alone. `None` for a ray alone in its
    /// replicate: its deposit counts in the gains unscaled (its square, the formula) and is
    /// left out of the error samples (a difference of mean `x` is no error sample).
    /// `signs` are the source patch's ([`source_signs`]).
    #[inline]
    pub fn push(&mut self, j: usize, r: usize, x: DVec3, scale: Option<f64>, signs: &Row) {
        let row = self.row_of(j);
        let sums = self.sums.get_mut(row);
        sums.squares += x * x;
        let slot = &mut sums.slot;
        if *slot == NO_SLOT {
            *slot = self.wave.len() as u32;
            self.wave.push((j as u32, Halves::default(), 0.0));
        }
        let (_, halves, squares) = &mut self.wave[*slot as usize];
        halves.push(r, x * scale.unwrap_or(1.0));
        *squares += x.length_squared();
        // The difference as the run's totals take it (a lone ray's value too).
        let y = x * scale.unwrap_or(1.0);
        let y = if r == 0 { y } else { -y };
        let y = [y.x as f32, y.y as f32, y.z as f32];
        for ((a, s), k) in self.projected.get_mut(row).iter_mut().zip(signs).zip(0..) {
            *a += *s * y[k % 3];
        }
        if let Some(s) = scale {
            // This wave's difference of the scaled replicates joins its group's pending error
            // power at once: the wave's rays are shot, and the group is the wave's.
            let d = if r == 0 { x * s } else { -x * s };
            add_sample(self.pending.get_mut(row), self.closed % SKETCHES, d);
            add_sample(self.raw.get_mut(row), self.closed % SKETCHES, d);
        }
    }

    /// Adds `x` (W² per channel) to patch `j`'s squares of deposits that the error samples
    /// do not hold.
    pub fn add_unsampled(&mut self, j: usize, x: DVec3) {
        let r = self.row_of(j);
        self.sums.get_mut(r).unsampled += x;
    }

    /// Per patch, in patch order: the sum of the squares of its deposits (W² per channel,
    /// the power its front kept from each ray) and the part of it the error samples do not
    /// hold ([`Waves::add_unsampled`]), zero for a patch no deposit reached.
    pub fn deposits(&self) -> (Vec<DVec3>, Vec<DVec3>) {
        let dense = |f: fn(&Sums) -> DVec3| -> Vec<DVec3> {
            self.row
                .iter()
                .map(|&s| f(sums_at(&self.sums, s)))
                .collect()
        };
        (dense(|s| s.squares), dense(|s| s.unsampled))
    }

    /// The entry of patch `j` in the rows, made (all zero) at its first deposit.
    fn row_of(&mut self, j: usize) -> usize {
        if self.row[j] == NO_SLOT {
            let len = self.sketch.len();
            for rows in [
                &mut self.sketch,
                &mut self.pending,
                &mut self.projected,
                &mut self.raw,
            ] {
                rows.push(ZERO_ROW);
            }
            self.recent.push([EMPTY; RECENT]);
            self.sums.push(NO_SUMS);
            self.row[j] = len as u32;
        }
        self.row[j] as usize
    }

    /// Closes a wave: its differences join the sums.
    pub fn end_wave(&mut self) {
        self.closed += 1;
        for (j, wave, v) in self.wave.drain(..) {
            let j = j as usize;
            let sums = self.sums.get_mut(self.row[j] as usize);
            sums.slot = NO_SLOT;
            sums.differences += wave.variance_of_sum();
            sums.model.0 += v;
            sums.model.1 += v * v;
            sums.total = sums.total.merge(wave);
            let f = self.face[j] as usize;
            let s = match self.face_slot[f] {
                NO_SLOT => {
                    self.face_slot[f] = self.face_wave.len() as u32;
                    self.face_wave.push((f as u32, DVec3::ZERO));
                    self.face_wave.len() - 1
                }
                s => s as usize,
            };
            if let Some((_, d)) = self.face_wave.get_mut(s) {
                *d += wave.sum[0] - wave.sum[1];
            }
        }
        for (f, d) in self.face_wave.drain(..) {
            self.face_slot[f as usize] = NO_SLOT;
            self.face_differences[f as usize] += d.length_squared();
        }
    }

    /// Ends the run (after the last [`Waves::end_wave`]): frees what only the waves need
    /// (the per-wave sums, the carried error power, the per-face sums of a wave), before the
    /// gains and the samples are measured, the run's peak of memory.
    pub fn end_run(&mut self) {
        self.face_slot = Vec::new();
        self.carrier = Vec::new();
        self.wave = Vec::new();
        self.carried = Vec::new();
        self.recent = Blocks::default();
        self.face_wave = Vec::new();
    }

    /// How much less of the per-wave variance a face's total keeps than a patch's: `kappa_F /
    /// kappa` (after the last [`Waves::end_wave`]), `kappa` the scene's ([`Waves::gains`])
    /// and `kappa_F = sum_f D_f / sum_f W_f` the same over the faces of several patches, `D_f`
    /// the run's one difference of the face's total and `W_f` the waves' summed. A patch's
    /// rays continue one sequence over the waves, so where they land is stratified across
    /// the waves as well as within each: over a whole face much more so than over one patch
    /// (a wall's mean under `prr` had a tenth of its patches' summed variance, the per-wave
    /// samples showed a fifth). The error samples ([`Waves::sketch`]) are the waves', scaled
    /// by `kappa`; the variance of a face's total from them takes this factor too
    /// (`crate::correlation`). 1 without a face of several patches.
    pub fn face_scale(&self) -> f64 {
        let mut count = vec![0u32; self.face_differences.len()];
        for &f in &self.face {
            count[f as usize] += 1;
        }
        let mut totals = vec![DVec3::ZERO; count.len()];
        // (a patch without a row adds zero)
        for (&slot, &f) in self.row.iter().zip(&self.face) {
            if slot != NO_SLOT {
                let t = &self.sums.get(slot as usize).total;
                totals[f as usize] += t.sum[0] - t.sum[1];
            }
        }
        let (mut d, mut w) = (0.0, 0.0);
        for ((total, &c), &waves) in totals.iter().zip(&count).zip(&self.face_differences) {
            if c > 1 {
                d += total.length_squared();
                w += waves;
            }
        }
        let kappa = self.kappa_by_sources();
        if w > 0.0 && kappa > 0.0 {
            d / w / kappa
        } else {
            1.0
        }
    }

    /// Each patch's gain (after the last [`Waves::end_wave`]), `face[j]` the input face of
    /// patch `j`. The per-wave differences miss the cancellation between the waves of one
    /// sequence, so they are scaled by `kappa = sum_j D_j / sum_j W_j` over the scene, `D_j`
    /// the run's one difference and `W_j` the sum of the waves' (the share of the per-wave
    /// variance the run keeps), here measured per source patch
    /// ([`Waves::kappa_by_sources`]: one degree of freedom per pair of patches a ray joined,
    /// not per patch). They also miss what the later waves make of a wave's error (shot on,
    /// it lands elsewhere: in a closed furnace of one patch per face an excess on one face
    /// takes `rho / 5` of itself from that face in the next waves), so they are scaled by
    /// [`Waves::carry_factor`] too, which the error samples measure (0.68-0.77 in that
    /// furnace at rho 0.9), taken only where it lowers the variance: the carrying rays add
    /// their own sampling noise to the samples (each carries its share of its patch's pending
    /// error to one patch), which on a subdivided furnace at rho 0.99, where most patches
    /// cast about a ray a wave, makes the factor 1.9-2.0 while the uncarried differences
    /// match the spread (0.99). Without the two, `shoot` on the furnaces of one patch per face
    /// reported 2.5x its spread (issue 36, item 2): 1.4x from the carrying, the rest from the
    /// noise of a `kappa` of 5 degrees of freedom (one run in 16 reported 5x the others).
    /// The faces' gains
    /// are then drawn towards those of the faces that received about as many deposits, not
    /// towards the formula ([`Toward::Alike`]): with tens of degrees of freedom a face
    /// measures gains of a few percent (a furnace of one patch per face) that the formula's
    /// pull would multiply.
    pub fn gains(&self, face: impl Iterator<Item = u32> + Clone) -> Vec<f64> {
        // The run's share of the per-wave variance, measured over (source, receiver) pairs, and
        // what the later waves' carrying makes of the error.
        let kappa = self.kappa_by_sources() * self.carry_factor().min(1.0);
        let measures = face.enumerate().map(move |(j, face)| {
            let sums = sums_at(&self.sums, self.row[j]);
            let (v, v2) = sums.model;
            let total = sums.total.sum[0] + sums.total.sum[1];
            Measure {
                face,
                replicate: (v > 0.0).then_some(kappa * sums.differences),
                model: v,
                dof: if v2 > 0.0 { v * v / v2 } else { 1.0 },
                deposits: if v > 0.0 {
                    total.length_squared() / v
                } else {
                    0.0
                },
            }
        });
        gains(measures, Toward::Alike)
    }
}

impl Waves {
    /// `kappa = sum_j D_j / sum_j W_j`, the share of the per-wave variance the run keeps
    /// (`D_j` the run's one replicate difference of patch `j` squared, `W_j` its waves'
    /// summed; 1 before anything was measured), with the run's difference of each patch taken
    /// apart by source patch. Used by the gains, the face scale and the error samples (whose
    /// variance, scaled by the one-difference-per-patch `kappa`, made the gathering methods'
    /// mean `z²` 1.6-2.3 on furnaces of one patch per face; 1.0-1.65 with this one). With
    /// `delta_ij` the run's replicate difference of what source `i` put on patch `j` (W per
    /// channel), `D_j = |sum_i delta_ij|²`; the sources' sequences
    /// are independent, so `E[D_j] = sum_i E[|delta_ij|²]`, which has a degree of freedom per
    /// (source, receiver) pair where `D_j` has one per receiver (5 in a furnace of one patch
    /// per face, where one run in 16 measured 2.4x the mean). Without a table of pairs,
    /// [`SKETCHES`] projections with signs `s_ik = ±1` of source `i` ([`source_signs`])
    /// estimate the sum: `E[|sum_i s_ik delta_ij|²] = sum_i E[|delta_ij|²]`, and the
    /// projections' mean has up to [`SKETCHES`] degrees of freedom per receiver. The cost: a
    /// row of [`SKETCHES`] × 3 adds per deposit.
    fn kappa_by_sources(&self) -> f64 {
        let (mut d, mut w) = (0.0, 0.0);
        for &slot in &self.row {
            let row = row_at(&self.projected, slot);
            let sums = sums_at(&self.sums, slot);
            if sums.model.0 > 0.0 {
                d += (0..SKETCHES)
                    .map(|g| sample(row, g).length_squared())
                    .sum::<f64>()
                    / SKETCHES as f64;
                w += sums.differences;
            }
        }
        if w > 0.0 { d / w } else { 1.0 }
    }

    /// How much of the error the later waves carry on: `sum_j sum_g |z_gj|² / sum_j sum_g
    /// |u_gj|²`, `z_gj` the error samples with what the later waves' rays carried
    /// ([`Waves::sketch`]) and `u_gj` without. 1 before anything was measured.
    fn carry_factor(&self) -> f64 {
        let (mut z, mut u) = (0.0, 0.0);
        for &slot in &self.row {
            let (row, pending, raw) = (
                row_at(&self.sketch, slot),
                row_at(&self.pending, slot),
                row_at(&self.raw, slot),
            );
            for g in 0..SKETCHES {
                z += (sample(row, g) + sample(pending, g)).length_squared();
                u += sample(raw, g).length_squared();
            }
        }
        if u > 0.0 { z / u } else { 1.0 }
    }

    /// The run's error samples (after the last [`Waves::end_wave`]), W per channel: per patch
    /// `sqrt(kappa) z_g`, `z_g` the wave differences of group `g` with what the later waves
    /// made of them. A wave's error `d_w` is power its patches then reflect: the later waves
    /// shoot it with their rays ([`Waves::ray`]), so `z_g = sum_{w in g} (I + K + K² + ...)
    /// d_w` as the run's own error is, `K` the transport of the rays cast (without it, in a
    /// closed furnace of one patch per face the samples overstated the error by about
    /// `1 / (1 - rho F)² = 1.4` at rho 0.9). The `d_w` are
    /// uncorrelated with mean zero, so `E[sum_g z_g z_g^T]` is the covariance of the run's
    /// error between *every* pair of patches (shooting conserves power, so its errors on
    /// neighbouring patches are correlated, often negatively): a linear
    /// function of the run's deposits, `sum_j c_j S_j`, has its variance estimated by
    /// `sum_g (sum_j c_j z_gj)²` with up to [`SKETCHES`] degrees of freedom. A gather from
    /// the run is such a function (`crate::schedule::combined`), and so is a face's power.
    /// Also returns the samples of the error power still pending and of the error power the
    /// finishing roulette dropped ([`Waves::drop_pending`]), each summed over the patches.
    /// The samples are kept where they were made, for the patches a deposit reached only
    /// ([`Sketch`]).
    pub fn sketch(self) -> (Sketch, [DVec3; SKETCHES], [DVec3; SKETCHES]) {
        let k = self.kappa_by_sources().sqrt();
        let dropped = self.dropped.map(|d| d * k);
        // What the samples need, the rest goes first.
        let (slots, mut sketch, pending) = {
            let waves = self;
            (waves.row, waves.sketch, waves.pending)
        };
        let mut sums = [DVec3::ZERO; SKETCHES];
        for &slot in &slots {
            let row = row_at(&pending, slot);
            for (g, p) in sums.iter_mut().enumerate() {
                *p += sample(row, g) * k;
            }
        }
        let k = k as f32;
        for (r, block) in sketch.blocks.iter_mut().enumerate() {
            for (x, row) in block.iter_mut().enumerate() {
                let pending = pending.get(r * ROW_BLOCK + x);
                *row = std::array::from_fn(|x| (row[x] + pending[x]) * k);
            }
        }
        let rows = Sketch {
            slot: slots,
            rows: sketch,
        };
        (rows, sums, dropped)
    }
}

/// Error samples of a shooting run ([`Waves::sketch`]), one [`Row`] per patch, kept only for
/// the patches a deposit reached (the rest are zero): 4 bytes a patch and 96 a patch reached,
/// where a dense array held 96 a patch (a run of fewer rays than patches reaches a few of
/// them).
#[derive(Debug, Clone, Default)]
pub(crate) struct Sketch {
    /// Per patch, its entry in `rows` ([`NO_SLOT`]: none, its samples zero).
    slot: Vec<u32>,
    /// The rows of the patches reached.
    rows: Rows,
}

impl Sketch {
    /// The number of patches (0 when no wave ran).
    pub fn len(&self) -> usize {
        self.slot.len()
    }

    /// Whether it has no patch.
    pub fn is_empty(&self) -> bool {
        self.slot.is_empty()
    }

    /// Patch `i`'s samples (`i < len`).
    #[inline]
    pub fn get(&self, i: usize) -> &Row {
        row_at(&self.rows, self.slot[i])
    }

    /// Each patch's samples, in patch order.
    pub fn iter(&self) -> impl Iterator<Item = &Row> {
        self.slot.iter().map(|&s| row_at(&self.rows, s))
    }

    /// Patch `i`'s samples to change, `None` for a patch without a row (its samples zero,
    /// which a change that keeps zero at zero leaves as they are).
    #[inline]
    pub fn get_mut(&mut self, i: usize) -> Option<&mut Row> {
        match self.slot[i] {
            NO_SLOT => None,
            s => Some(self.rows.get_mut(s as usize)),
        }
    }

    /// One row per patch, in patch order (the rows go as they are copied).
    pub fn into_dense(self) -> Vec<Row> {
        let mut dense = vec![ZERO_ROW; self.slot.len()];
        for (d, &s) in dense.iter_mut().zip(&self.slot) {
            if s != NO_SLOT {
                *d = *self.rows.get(s as usize);
            }
        }
        dense
    }
}

/// Rays alone in their replicate paired across waves into error samples.
///
/// A patch casting one ray in a wave (the late waves' small holders, the finishing roulette's
/// survivors) has no partner of the other replicate in it, so the wave's difference cannot
/// hold that ray's error. But a patch's sequence goes on over the waves and its rays alternate
/// between the two independent replicates, so its next lone ray of the other replicate is an
/// independent ray from the same patch, of the same distribution. With `h` a ray's deposits
/// per unit power (`rho_j` on the patch `j` whose front it hits, 0 elsewhere) and `p_a`,
/// `p_b` the powers the two rays carry (per channel), the pair's error is
/// `p_a (h_a - F) + p_b (h_b - F)` and
///
/// ```text
/// d = c (h_a - h_b),   c = sqrt((p_a² + p_b²) / 2)
/// ```
///
/// has mean zero and the same covariance over the patches, `(p_a² + p_b²) Cov(h)`. It joins
/// the error samples of the wave that closes the pair as error power its patches reflect
/// ([`Waves::add_error`]), carried on as the waves' differences are, so the gathers' images
/// hold it as they hold the waves'. Before, lone rays were left to the
/// independent-ray formula (`Shooting::unsampled`): under quasi-Monte Carlo rays a patch's
/// lone rays are stratified over the waves, so the formula overstated them, and the gathers
/// of `combined`'s passes, which inherit each pass's shooting, saw only the last pass's part
/// (issue 36: `combined` on a furnace of one patch per face at rho 0.99 reported 1.5x its
/// spread at 2e5 rays and 0.6x at 2e4). A ray left without a partner at the end, or followed
/// by another of its own replicate, keeps the formula. (Their errors carried on, the samples
/// need the quiet carry of [`RECENT`] and the future of what is left pending at the run's end
/// (`crate::shoot`): without either, their total over the scene, which shooting conserves,
/// grew to hundreds of times the error.)
#[derive(Debug, Default)]
pub(crate) struct LoneRays {
    /// Per patch holding one, its unpaired lone ray.
    open: std::collections::HashMap<u32, LoneRay>,
}

/// A lone ray waiting for its pair ([`LoneRays`]): its replicate, the patch it kept power on
/// (`None`: it kept nothing on a front face) and its power per channel (W).
type LoneRay = (usize, Option<u32>, DVec3);

impl LoneRays {
    /// A lone ray of replicate `r` from patch `source` carrying `power` (W per channel) that
    /// left `kept` (`rho_j` of its power) on the front of patch `j`, or nothing. `rho` gives a
    /// patch's reflectance. Returns a ray whose error stays with the formula: `(j, kept)` of
    /// an earlier lone ray of the same replicate that this one replaces.
    pub fn ray(
        &mut self,
        source: u32,
        r: usize,
        hit: Option<u32>,
        power: DVec3,
        waves: &mut Waves,
        rho: impl Fn(u32) -> DVec3,
    ) -> Option<(u32, DVec3)> {
        match self.open.remove(&source) {
            Some((r0, j0, p0)) if r0 != r => {
                let c = ((p0 * p0 + power * power) / 2.0).powf(0.5);
                if let Some(j) = j0 {
                    waves.add_error(j as usize, c * rho(j));
                }
                if let Some(j) = hit {
                    waves.add_error(j as usize, -c * rho(j));
                }
                None
            }
            older => {
                self.open.insert(source, (r, hit, power));
                older.and_then(|(_, j, p)| j.map(|j| (j, rho(j) * p)))
            }
        }
    }

    /// The rays left unpaired, `(j, kept)` for those that kept power on a patch, in patch
    /// order (the same for any thread count).
    pub fn unpaired(self, rho: impl Fn(u32) -> DVec3) -> Vec<(u32, DVec3)> {
        let mut left: Vec<(u32, LoneRay)> = self.open.into_iter().collect();
        left.sort_by_key(|(source, _)| *source);
        left.into_iter()
            .filter_map(|(_, (_, j, p))| j.map(|j| (j, rho(j) * p)))
            .collect()
    }
}

/// What a face's gain is drawn towards ([`gains`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Toward {
    /// Gain 1, the independent-ray formula: for measures of one degree of freedom a patch.
    Formula,
    /// The gain of the faces that received about as many deposits (per patch, within a
    /// factor 2: [`Measure::deposits`]), `sum q / sum v` over them, itself drawn towards the
    /// scene's with the weight of [`PRIOR_ALIKE`] degrees of freedom. Stratification gains
    /// nothing on a patch that receives a deposit or two, and most where hundreds land: in a
    /// room lit by a 1 cm² light the gain of its 0.25 m squares was 0.53, of its 1 cm squares
    /// 0.99, and the scene's (0.54, the large squares' variance being most of the scene's)
    /// made the 1 cm squares of one patch per face report 0.62 of their spread (issue 36).
    Alike,
}

/// The degrees of freedom with which the scene's gain weighs in the gain of a class of faces
/// that received about as many deposits ([`Toward::Alike`]).
pub(crate) const PRIOR_ALIKE: f64 = 8.0;

/// The class of an item that received `deposits` deposits ([`Toward::Alike`]): `floor(log2)`,
/// below 1 in class 0.
fn deposit_class(deposits: f64) -> usize {
    if deposits >= 2.0 {
        (deposits.log2().floor() as usize).min(63)
    } else {
        0
    }
}

/// Each item's gain `g_f` ([module](self)), in the order of `items`.
/// The measures are read three times over (`items` is cloned), not collected: 48 bytes an
/// item less at shooting's peak of memory.
pub(crate) fn gains<I>(items: I, toward: Toward) -> Vec<f64>
where
    I: IntoIterator<Item = Measure>,
    I::IntoIter: Clone,
{
    let items = items.into_iter();
    let n_faces = items
        .clone()
        .map(|m| m.face as usize + 1)
        .max()
        .unwrap_or(0);
    let (mut q, mut v, mut dof) = (vec![0.0; n_faces], vec![0.0; n_faces], vec![0.0; n_faces]);
    // per face: deposits summed over its measured patches, and their count (what the classes
    // of `Toward::Alike` read; the formula's gain needs neither)
    let alike = toward == Toward::Alike;
    let per_face = |x| if alike { vec![x; n_faces] } else { Vec::new() };
    let (mut deposits, mut count) = (per_face(0.0), vec![0u32; if alike { n_faces } else { 0 }]);
    for m in items.clone() {
        if let Some(r) = m.replicate {
            let f = m.face as usize;
            q[f] += r;
            v[f] += m.model;
            dof[f] += m.dof;
            if alike {
                deposits[f] += m.deposits;
                count[f] += 1;
            }
        }
    }
    let (q_all, v_all) = (q.iter().sum::<f64>(), v.iter().sum::<f64>());
    let scene = if v_all > 0.0 { q_all / v_all } else { 1.0 };
    // The target of each face: the formula's gain 1, or its class's.
    let class_of = |f: usize| deposit_class(deposits[f] / f64::from(count[f].max(1)));
    let targets: Vec<f64> = match toward {
        Toward::Formula => vec![1.0; 64],
        Toward::Alike => {
            let (mut cq, mut cv, mut cdof) = ([0.0; 64], [0.0; 64], [0.0; 64]);
            for f in (0..n_faces).filter(|&f| v[f] > 0.0) {
                let c = class_of(f);
                cq[c] += q[f];
                cv[c] += v[f];
                cdof[c] += dof[f];
            }
            (0..64)
                .map(|c| {
                    if cv[c] <= 0.0 || cdof[c] <= 0.0 {
                        return scene;
                    }
                    let prior = PRIOR_ALIKE * cv[c] / cdof[c];
                    (cq[c] + prior * scene) / (cv[c] + prior)
                })
                .collect()
        }
    };
    // Each face's gain, made over its sums `q` (4 arrays a face less at the gathers' peak).
    for f in 0..n_faces {
        let target = if alike { targets[class_of(f)] } else { 1.0 };
        q[f] = if dof[f] <= 0.0 || v[f] <= 0.0 {
            target
        } else {
            let prior = PRIOR_PATCHES * v[f] / dof[f];
            (q[f] + prior * target) / (v[f] + prior)
        };
    }
    drop((v, dof, deposits, count));
    let face_gain = q;
    items.map(|m| face_gain[m.face as usize]).collect()
}

/// Face numbers (one per patch) for tables per face no longer than the patches: as they are
/// when they are below the patch count, else renumbered `0..F` in their order, `F` the faces
/// present. What [`Waves`] groups by is the same, and its sums over faces run in the same
/// order.
pub(crate) fn dense_faces(face: impl Iterator<Item = u32> + Clone) -> Vec<u32> {
    let (patches, largest) = face
        .clone()
        .fold((0usize, 0u32), |(n, m), f| (n + 1, m.max(f)));
    if (largest as usize) < patches {
        return face.collect();
    }
    let mut present: Vec<u32> = face.clone().collect();
    present.sort_unstable();
    present.dedup();
    face.map(|f| present.partition_point(|&g| g < f) as u32)
        .collect()
}

/// `v * gain` per patch: the variances scaled by their gains.
pub(crate) fn scale(variance: &mut [DVec3], gains: &[f64]) {
    for (v, g) in variance.iter_mut().zip(gains) {
        *v *= *g;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faces_renumbered_densely_keep_their_order_and_groups() {
        let face = [7u32, 3, 900, 7, 3];
        assert_eq!(dense_faces(face.iter().copied()), vec![1, 0, 2, 1, 0]);
        // numbers below the patch count stay as they are
        let small = [2u32, 0, 2, 1];
        assert_eq!(dense_faces(small.iter().copied()), small.to_vec());
        assert!(dense_faces(std::iter::empty()).is_empty());
    }

    /// The bytes `v` holds on the heap.
    fn b<T>(v: &Vec<T>) -> usize {
        v.capacity() * size_of::<T>()
    }

    /// The bytes `r` holds on the heap.
    fn rows_bytes(r: &Rows) -> usize {
        b(&r.blocks) + r.blocks.iter().map(b).sum::<usize>()
    }

    /// The bytes `w` holds on the heap (its arrays' capacities).
    fn heap_bytes(w: &Waves) -> usize {
        let rows = rows_bytes;
        b(&w.row)
            + b(&w.wave)
            + b(&w.sums.blocks)
            + w.sums.blocks.iter().map(b).sum::<usize>()
            + rows(&w.sketch)
            + rows(&w.pending)
            + b(&w.recent.blocks)
            + w.recent.blocks.iter().map(b).sum::<usize>()
            + b(&w.carrier)
            + b(&w.carried)
            + b(&w.face)
            + b(&w.face_slot)
            + b(&w.face_wave)
            + b(&w.face_differences)
            + rows(&w.projected)
            + rows(&w.raw)
    }

    #[test]
    fn waves_hold_24_bytes_a_patch_and_rows_where_deposits_land() {
        // Memory per element (issue 35): 12 bytes a patch (its face, row and carrier), 12 a
        // face;
        // the run's sums (128, shooting's squares of deposits among them) and the
        // error samples' rows (384) made at a patch's first deposit, a wave's sums sparse.
        let n = 5000;
        let mut w = Waves::new((0..n as u32).collect());
        assert_eq!(heap_bytes(&w), 24 * n);
        let sums = |w: &Waves, j: usize| *sums_at(&w.sums, w.row[j]);
        let signs = source_signs(0);
        let x = DVec3::new(1.0, 2.0, 3.0);
        let mut counts = vec![0u64; n];
        counts[0] = 4;
        w.begin_wave(&counts);
        // A zero deposit first, then one of each replicate, on patch 7.
        w.push(7, 0, DVec3::ZERO, Some(1.0), &signs);
        w.push(7, 0, x, Some(1.0), &signs);
        w.push(7, 1, 0.5 * x, Some(1.0), &signs);
        w.end_wave();
        let (d, v) = ((0.5 * x).length_squared(), 1.25 * x.length_squared());
        assert_eq!(sums(&w, 7).differences, d);
        assert_eq!(sums(&w, 7).model, (v, v * v));
        assert_eq!(w.face_differences[7], d);
        assert_eq!(sums(&w, 6).differences, 0.0);
        // The next wave starts from nothing.
        w.begin_wave(&counts);
        w.push(7, 1, x, Some(1.0), &signs);
        w.end_wave();
        assert_eq!(sums(&w, 7).differences, d + x.length_squared());
        assert_eq!(sums(&w, 7).total.sum, [x, 1.5 * x]);
        assert_eq!(w.face_differences[7], d + x.length_squared());
        // One patch with rows: one block of each.
        assert_eq!(w.row.iter().filter(|&&r| r != NO_SLOT).count(), 1);
        let rows = [&w.sketch, &w.pending, &w.projected, &w.raw];
        let row_bytes: usize = rows.iter().map(|r| rows_bytes(r)).sum();
        assert!(rows.iter().all(|r| r.len() == 1 && r.blocks.len() == 1));
        // (a block's rows, and the list of blocks: room for 4)
        assert!(row_bytes <= 4 * (size_of::<Row>() * ROW_BLOCK + 4 * size_of::<Vec<Row>>()));
        let sums_bytes = b(&w.sums.blocks) + w.sums.blocks.iter().map(b).sum::<usize>();
        assert_eq!(w.sums.len(), 1);
        assert!(sums_bytes <= size_of::<Sums>() * ROW_BLOCK + 4 * size_of::<Vec<Sums>>());
        w.end_run();
        assert_eq!(heap_bytes(&w), 16 * n + row_bytes + sums_bytes);
    }

    /// A source whose lone rays keep power on patch 1 (probability 0.3, reflectance 0.5) or
    /// patch 2 (0.5, reflectance 0.8) or nothing (0.2), with powers that differ from ray to
    /// ray: the pair samples' squares must average `(p_a² + p_b²) Var(h_j)` on each patch and
    /// their products `(p_a² + p_b²) Cov(h_1, h_2)`, the pair's own error. 20,000 independent
    /// pairs; 5 standard errors of the mean square (about 1% each): a false failure below 1e-6.
    #[test]
    fn lone_rays_paired_across_waves_sample_their_error() {
        let rho = |j: u32| DVec3::splat([0.0, 0.5, 0.8][j as usize]);
        let (f1, f2) = (0.3, 0.5);
        let var = |f: f64, r: f64| r * r * f * (1.0 - f);
        let cov = -0.5 * 0.8 * f1 * f2;
        let mut stream = mcrad_random::Stream::new(7, 0, 0, 0);
        let mut draw = || {
            let u = stream.uniform_f64();
            (u < f1).then_some(1).or((u < f1 + f2).then_some(2))
        };
        let pairs = 20_000;
        let (mut s11, mut s22, mut s12) = (vec![], vec![], vec![]);
        for k in 0..pairs {
            let mut waves = Waves::new(vec![0, 1, 2]);
            let mut lone = LoneRays::default();
            let (pa, pb) = (1.0 + (k % 3) as f64, 0.5 + (k % 5) as f64);
            assert!(
                lone.ray(0, 0, draw(), DVec3::splat(pa), &mut waves, rho)
                    .is_none()
            );
            assert!(
                lone.ray(0, 1, draw(), DVec3::splat(pb), &mut waves, rho)
                    .is_none()
            );
            assert!(lone.unpaired(rho).is_empty());
            let (rows, _, _) = waves.sketch();
            let (d1, d2) = (f64::from(rows.get(1)[0]), f64::from(rows.get(2)[0]));
            let c2 = (pa * pa + pb * pb) / 2.0;
            s11.push(d1 * d1 / (2.0 * c2));
            s22.push(d2 * d2 / (2.0 * c2));
            s12.push(d1 * d2 / (2.0 * c2));
        }
        for (name, s, want) in [
            ("patch 1", &s11, var(f1, 0.5)),
            ("patch 2", &s22, var(f2, 0.8)),
            ("patches 1 and 2", &s12, cov),
        ] {
            let n = s.len() as f64;
            let mean = s.iter().sum::<f64>() / n;
            let sd = (s.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
            assert!(
                (mean - want).abs() < 5.0 * sd / n.sqrt(),
                "{name}: {mean:.5} against {want:.5} (± {:.5})",
                sd / n.sqrt()
            );
        }
    }

    /// A lone ray followed by another of its own replicate is not an independent pair: the
    /// earlier one goes back to the formula, and one left at the end is unpaired.
    #[test]
    fn lone_rays_of_one_replicate_are_not_paired() {
        let rho = |_: u32| DVec3::splat(0.5);
        let mut waves = Waves::new(vec![0, 1]);
        let mut lone = LoneRays::default();
        assert!(
            lone.ray(0, 0, Some(1), DVec3::ONE, &mut waves, rho)
                .is_none()
        );
        assert_eq!(
            lone.ray(0, 0, None, DVec3::ONE, &mut waves, rho),
            Some((1, DVec3::splat(0.5)))
        );
        assert!(
            lone.ray(1, 1, Some(0), DVec3::splat(2.0), &mut waves, rho)
                .is_none()
        );
        assert_eq!(lone.unpaired(rho), vec![(0, DVec3::ONE)]);
        assert!(waves.sketch().0.iter().all(|row| *row == ZERO_ROW));
    }

    #[test]
    fn halves_measure_the_variance_of_a_mean_and_of_a_sum() {
        let mut h = Halves::default();
        for (k, x) in [1.0, 3.0, 2.0, 6.0].into_iter().enumerate() {
            h.push(k % 2, DVec3::new(x, 0.0, 0.0));
        }
        // Means 1.5 and 4.5, two each: (3)² / 4.
        assert_eq!(h.variance_of_mean(4), Some(9.0 / 4.0));
        // Sums 3 and 9.
        assert_eq!(h.variance_of_sum(), 36.0);
        assert_eq!(Halves::default().variance_of_mean(1), None);
        // Signed: (1.5 - 4.5) * 2 / 4, its square the variance of the mean.
        assert_eq!(h.error_of_mean(4), DVec3::new(-1.5, 0.0, 0.0));
        assert_eq!(Halves::default().error_of_mean(1), DVec3::ZERO);
        let (a, b) = (h, Halves::default());
        assert_eq!(a.merge(b), h);
    }

    #[test]
    fn a_face_of_few_deposits_is_drawn_towards_the_gain_of_its_like() {
        // 50 faces of 100 deposits each measure gain 0.25 (most of the scene's variance), 50
        // faces of one deposit measure gain 1 with one degree of freedom each: drawn towards
        // the scene's gain (0.257) the latter would report 0.41 of their variance; towards
        // their class's (0.897), 0.918.
        let heavy = |face| Measure {
            face,
            replicate: Some(0.25),
            model: 1.0,
            dof: 20.0,
            deposits: 100.0,
        };
        let light = |face| Measure {
            face,
            replicate: Some(0.01),
            model: 0.01,
            dof: 1.0,
            deposits: 1.0,
        };
        let g = gains(
            (0..100).map(|f| if f < 50 { heavy(f) } else { light(f) }),
            Toward::Alike,
        );
        let scene = (50.0 * 0.25 + 50.0 * 0.01) / (50.0 + 50.0 * 0.01);
        let prior = PRIOR_ALIKE * 0.5 / 50.0;
        let class = (0.5 + prior * scene) / (0.5 + prior);
        let face = (0.01 + 4.0 * 0.01 * class) / (0.01 + 4.0 * 0.01);
        assert!(
            (g[99] - face).abs() < 1e-12 && g[99] > 0.9,
            "{} vs {face}",
            g[99]
        );
        let prior = PRIOR_ALIKE * 50.0 / 1000.0;
        let class = (12.5 + prior * scene) / (50.0 + prior);
        let face = (0.25 + 4.0 / 20.0 * class) / (1.0 + 4.0 / 20.0);
        assert!((g[0] - face).abs() < 1e-12, "{} vs {face}", g[0]);
    }

    #[test]
    fn a_face_gain_is_its_own_measure_drawn_towards_the_formula() {
        // Face 0 measures gain 0.25 over 100 patches, face 1 gain 0.25 over 1 patch.
        let measure = |face| Measure {
            face,
            replicate: Some(0.25),
            model: 1.0,
            dof: 1.0,
            deposits: 0.0,
        };
        let g = gains(
            (0..101).map(|i| measure(u32::from(i == 100))),
            Toward::Formula,
        );
        let face0 = (25.0 + 4.0) / 104.0;
        let face1 = (0.25 + 4.0) / 5.0;
        assert!(
            (g[0] - face0).abs() < 1e-12 && (g[100] - face1).abs() < 1e-12,
            "{g:?}"
        );
        // Nothing measured: the formula stands.
        let unmeasured = Measure {
            replicate: None,
            ..measure(0)
        };
        assert_eq!(
            gains([unmeasured, unmeasured], Toward::Formula),
            vec![1.0, 1.0]
        );
    }
}
