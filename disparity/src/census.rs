//! The census-refine engine: the network's disparity, refined by a census (Hamming) search around it.
//!
//! Why: the network answers everywhere but coarsely (slanted planes on 8x8 px tiles, trained on rendered
//! scenes only), so on real photographs its error is mostly a few pixels off, seldom far off. A local census
//! match within [`SEARCH_PX`] of its answer corrects that at a fraction of a full search's cost: costs are
//! Hamming distances of 5x5 census codes, aggregated per offset over a [`WINDOW`] x [`WINDOW`] box (each
//! pixel's offset is relative to its own network disparity, so slanted surfaces stay matched), winner take
//! all, then a parabola through the best cost and its neighbours for the sub-pixel part; a winner that is not
//! unique ([`UNIQUENESS_PCT`]) leaves the network's answer. Where the engine's resolution is larger than the
//! network's, SGBM_3WAY's checked matches at the network's resolution replace its answer first (`Prior`),
//! the search runs there and the answer is upsampled (again searched at the engine's resolution only beyond
//! [`FINE_ABOVE`] times the network's width). Census compares
//! signs of local intensity differences, so the gain and offset differences of real camera pairs do not move
//! it. The parameters were chosen on Aloe (Middlebury, opencv-doc); Motorcycle is held out
//! (models/hitnet/README.md). Every buffer of its own is allocated at construction: nothing per frame
//! (OpenCV's SGBM keeps its working buffers inside the call).
use std::ops::Range;

use crate::census_confidence::{Scorer, AT_EDGE, MARGIN_ONE};
use crate::confidence::reason;
use crate::engine::{check_sizes, DisparityEngine};
use crate::error::{DisparityError, Result};
use crate::match_cost::{Codes, MatchCost};
use crate::onnx::OnnxEngine;
use crate::resample::{nearest, resize_gray, upsample_disparity};
use crate::sgbm::SgbmEngine;

/// Offsets searched around the network's disparity: -SEARCH_PX..=SEARCH_PX (px at the engine's resolution).
pub const SEARCH_PX: i32 = 3;
/// Side of the cost aggregation box (px).
pub const WINDOW: usize = 7;
/// A census winner replaces the network's answer only where every offset beyond its neighbours costs this
/// much (%) more: on flat or repetitive texture the network stays. Chosen on Aloe and the rendered fixture
/// (whose depth error the unchecked refinement doubled: abs_rel 0.045 vs the network's 0.021; 10 %: 0.035;
/// 30 %: 0.025, Aloe bad-2 17.7 % -> 19.4 %).
pub const UNIQUENESS_PCT: u32 = 30;
/// Matching window of the SGBM prior (px at the network's resolution; block 3 there is block 6 at twice it).
/// Chosen on Aloe and the rendered fixture against OpenCV's usual 5 (with searches at 320x240 and 640x480):
/// bad-2 16.9 vs 17.7 %, abs_rel 0.032 vs 0.033 (7: 18.5 %).
pub const PRIOR_BLOCK: i32 = 3;
/// Radius of the census window (5x5: 24 bits).
const CENSUS_R: usize = 2;
/// Cost of a match outside the right image: every census bit differs.
const OUTSIDE: u8 = ((2 * CENSUS_R + 1) * (2 * CENSUS_R + 1) - 1) as u8;
const OFFSETS: usize = (2 * SEARCH_PX + 1) as usize;

/// The network's disparity refined by a census search around it (see the module docs).
pub struct CensusRefineEngine {
    name: String,
    net: OnnxEngine,
    size: (u32, u32),
    /// The pair at the network's resolution (used only when it differs from the engine's).
    net_left: Vec<u8>,
    net_right: Vec<u8>,
    net_disp: Vec<f32>,
    /// SGBM's accepted matches at the network's resolution, when the engine's is larger (see [`Prior`]).
    prior: Option<Prior>,
    /// The refinement at the network's own resolution, when the engine's is larger, and its answer. Why: a
    /// search of +-[`SEARCH_PX`] at the engine's resolution spans fewer of the network's pixels (+-1.5 of them
    /// at twice its size), too few to correct its errors of a few of its pixels. (Aloe at its own 1282x1110,
    /// the network at 640x480: bad-2 28.8 % with a pass at the engine's resolution alone, against SGBM_3WAY's
    /// 30.0 %; see models/hitnet/README.md.)
    coarse: Option<(Pass, Vec<f32>)>,
    /// The refinement at the engine's resolution: where the network runs at it (or above it), or at less than
    /// 1 / [`FINE_ABOVE`] of its width.
    fine: Option<Pass>,
    /// The guess of the pass at the engine's resolution (engine pixels).
    guess: Vec<f32>,
    /// The second thread: what does not need the network while it runs, half of each refinement.
    helper: Helper,
    /// The network's own answer at its resolution, before the prior replaced part of it (with a prior only).
    net_raw: Vec<f32>,
    /// The confidence's scoring at the last pass's resolution, and its answer there when that is not the
    /// engine's (`conf_pass`, `why_pass`).
    scorer: Scorer,
    conf_pass: Vec<f32>,
    why_pass: Vec<u8>,
    /// The last frame's confidence and reasons at the engine's resolution.
    conf: Vec<f32>,
    why: Vec<u8>,
    /// The answer's match cost at the engine's resolution pooled onto the scored grid (a feature of the
    /// confidence), and both images' census codes at the engine's resolution on the rows it matches
    /// ([`MatchCost::rows`]) when no pass there computes them.
    cost: MatchCost,
    full_census: Option<[Vec<u32>; 2]>,
    /// Whether the confidence is computed (the paired benchmark's baseline turns it off).
    scoring: bool,
}

/// A second refinement at the engine's resolution runs only where the engine is more than this many times the
/// network's width. At twice it, the pass at the network's resolution upsampled was as good (Aloe at 640x480,
/// hitnet-s with the prior: bad-2 17.3 vs 16.9 %; the rendered fixture: abs_rel 0.030 vs 0.032) and the
/// second pass cost 8 ms of CPU per frame; at four times it (Aloe at its 1282x1110, hitnet-s) it took bad-2
/// from 25.0 to 22.4 %.
pub const FINE_ABOVE: f64 = 2.0;

/// One refinement's buffers at one resolution: both census images, the search centres, the row window.
struct Pass {
    w: usize,
    h: usize,
    census_l: Vec<u32>,
    census_r: Vec<u32>,
    base: Vec<i32>,
    rows: RowWindow,
    /// Each pixel's search outcome ([`winner`]'s margin byte and window-edge bit), for the confidence.
    stat: Vec<u8>,
}

impl Pass {
    fn new(w: usize, h: usize) -> Pass {
        Pass {
            w,
            h,
            census_l: vec![0; w * h],
            census_r: vec![0; w * h],
            base: vec![0; w * h],
            rows: RowWindow::new(w),
            stat: vec![0; w * h],
        }
    }

    /// The census of `left` and `right` (this pass's size), as a job for the helper.
    fn census_job(&mut self, left: &[u8], right: &[u8]) -> CensusJob {
        CensusJob {
            imgs: [left.as_ptr(), right.as_ptr()],
            outs: [self.census_l.as_mut_ptr(), self.census_r.as_mut_ptr()],
            w: self.w,
            h: self.h,
        }
    }

    /// The refinement of `guess` into `out`: the lower half on the helper, the upper here.
    fn refine(&mut self, helper: &Helper, guess: &[f32], out: &mut [f32]) -> Result<()> {
        let (w, h) = (self.w, self.h);
        round_into(guess, &mut self.base);
        let mid = h / 2;
        let (top, bottom) = out.split_at_mut(mid * w);
        let (stat_top, stat_bottom) = self.stat.split_at_mut(mid * w);
        helper.run(Job::Refine {
            cl: self.census_l.as_ptr(),
            cr: self.census_r.as_ptr(),
            base: self.base.as_ptr(),
            guess: guess.as_ptr(),
            out: bottom.as_mut_ptr(),
            stat: stat_bottom.as_mut_ptr(),
            w,
            h,
            y0: mid,
        })?;
        refine(&self.census_l, &self.census_r, &self.base, guess, h, 0..mid, &mut self.rows, top, stat_top);
        helper.wait()
    }
}

/// SGBM at the network's resolution (OpenCV's checks: uniqueness 10 %, left-right within 1 px, speckles), its
/// accepted matches in place of the network's answer before the first refinement. Why: the network (slanted
/// planes on 8x8 px tiles, trained on rendered scenes) misses thin structures and is off by more than the
/// searches reach on real photographs; where SGBM passes its own checks it is right to a fraction of a pixel
/// (models/hitnet/README.md). At a quarter of the pixels and the network's range plus 8 px (48 against the
/// runtime's 96 at 640x480) it searches an eighth of SGBM's cells at 640x480, and it runs from the helper thread (SGBM_3WAY, on OpenCV's pool) while the network
/// runs. The band at the left edge it cannot search keeps the network's answer.
struct Prior {
    disp: Vec<f32>,
}

/// What the helper thread is asked to do. Raw parts of the engine's buffers: the engine waits for the
/// answer before it touches them again or returns, so they outlive the job and nobody else writes them.
#[derive(Clone, Copy)]
enum Job {
    /// What does not need the network: each census (images of w x h into their outputs), then, when given,
    /// the helper's SGBM on the pair at the network's resolution into `sgbm.1`.
    Prepare { census: [Option<CensusJob>; 2], sgbm: Option<([*const u8; 2], *mut f32)> },
    /// Rows `y0..h` of the refinement into `out` (those rows).
    Refine {
        cl: *const u32,
        cr: *const u32,
        base: *const i32,
        guess: *const f32,
        out: *mut f32,
        stat: *mut u8,
        w: usize,
        h: usize,
        y0: usize,
    },
    /// A closure of the engine's, run here (the engine keeps it alive until `done`: see [`erase`]).
    Call(*mut (dyn FnMut() + Send + 'static)),
}

/// Both images' census codes.
#[derive(Clone, Copy)]
struct CensusJob {
    imgs: [*const u8; 2],
    outs: [*mut u32; 2],
    w: usize,
    h: usize,
}

// SAFETY: the pointers are only dereferenced on the helper thread while the sending thread waits (see Job).
unsafe impl Send for Job {}

/// `f` as a [`Job::Call`], its borrows' lifetime erased.
///
/// # Safety
/// The caller keeps `f` alive and waits for the job's `done` before it returns or uses anything `f` borrows.
unsafe fn erase<'a>(f: &'a mut (dyn FnMut() + Send + 'a)) -> *mut (dyn FnMut() + Send + 'static) {
    // SAFETY: only the lifetime changes (see the contract above)
    unsafe { std::mem::transmute::<*mut (dyn FnMut() + Send + 'a), *mut (dyn FnMut() + Send + 'static)>(f) }
}

/// A persistent second thread (spawned once: spawning per frame would allocate) and its two channels,
/// which allocate nothing per message once warmed up at construction.
struct Helper {
    jobs: Option<crossbeam_channel::Sender<Job>>,
    done: crossbeam_channel::Receiver<Result<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Helper {
    /// The thread, with a row window for each refinement's width, owning the prior's SGBM if any.
    fn new(widths: &[usize], mut sgbm: Option<SgbmEngine>) -> Result<Helper> {
        let mut wins: Vec<RowWindow> = widths.iter().map(|&w| RowWindow::new(w)).collect();
        let (jobs, jobs_rx) = crossbeam_channel::bounded::<Job>(1);
        let (done_tx, done) = crossbeam_channel::bounded::<Result<()>>(1);
        let thread = std::thread::Builder::new()
            .name("abvs-census".into())
            .spawn(move || {
                for job in jobs_rx.iter() {
                    let mut answer = Ok(());
                    // SAFETY: see Job: the buffers are the engine's, untouched until it receives `done`.
                    unsafe {
                        match job {
                            Job::Prepare { census: jobs, sgbm: pair } => {
                                for CensusJob { imgs, outs, w, h } in jobs.into_iter().flatten() {
                                    for (img, out) in imgs.into_iter().zip(outs) {
                                        census(
                                            std::slice::from_raw_parts(img, w * h),
                                            w,
                                            h,
                                            std::slice::from_raw_parts_mut(out, w * h),
                                        )
                                    }
                                }
                                if let (Some(([l, r], out)), Some(sg)) = (pair, sgbm.as_mut()) {
                                    let n = (sg.size().0 * sg.size().1) as usize;
                                    answer = sg.compute(
                                        std::slice::from_raw_parts(l, n),
                                        std::slice::from_raw_parts(r, n),
                                        std::slice::from_raw_parts_mut(out, n),
                                    );
                                }
                            }
                            Job::Call(f) => (*f)(),
                            Job::Refine { cl, cr, base, guess, out, stat, w, h, y0 } => {
                                let n = w * h;
                                let Some(win) = wins.iter_mut().find(|r| r.w == w) else {
                                    let e = format!("census-refine: no row window for width {w}");
                                    let _ = done_tx.send(Err(DisparityError::Invalid(e)));
                                    continue;
                                };
                                refine(
                                    std::slice::from_raw_parts(cl, n),
                                    std::slice::from_raw_parts(cr, n),
                                    std::slice::from_raw_parts(base, n),
                                    std::slice::from_raw_parts(guess, n),
                                    h,
                                    y0..h,
                                    win,
                                    std::slice::from_raw_parts_mut(out, (h - y0) * w),
                                    std::slice::from_raw_parts_mut(stat, (h - y0) * w),
                                )
                            }
                        }
                    }
                    if done_tx.send(answer).is_err() {
                        break;
                    }
                }
            })
            .map_err(|e| DisparityError::Invalid(format!("census-refine: helper thread: {e}")))?;
        let helper = Helper { jobs: Some(jobs), done, thread: Some(thread) };
        // a round trip now, so the channels' waiter lists exist before the first frame
        let (img, mut out) = ([0u8; 64], [[0u32; 64]; 2]);
        let [a, b] = &mut out;
        helper.run(Job::Prepare {
            census: [
                Some(CensusJob {
                    imgs: [img.as_ptr(), img.as_ptr()],
                    outs: [a.as_mut_ptr(), b.as_mut_ptr()],
                    w: 8,
                    h: 8,
                }),
                None,
            ],
            sgbm: None,
        })?;
        helper.wait()?;
        Ok(helper)
    }

    /// Hands `job` to the thread; [`Helper::wait`] must follow before its buffers are used again.
    fn run(&self, job: Job) -> Result<()> {
        let gone = || DisparityError::Invalid("census-refine: the helper thread ended".into());
        self.jobs.as_ref().ok_or_else(gone)?.send(job).map_err(|_| gone())
    }

    /// Hands `job` to the thread; the answer's [`Pending::wait`], or its drop (also when this thread unwinds),
    /// waits for it: a job that borrows this thread's stack never outlives it.
    fn start(&self, job: Job) -> Result<Pending<'_>> {
        self.run(job)?;
        Ok(Pending(Some(self)))
    }

    /// The job's answer (the prior's SGBM can fail).
    fn wait(&self) -> Result<()> {
        self.done.recv().map_err(|_| DisparityError::Invalid("census-refine: the helper thread ended".into()))?
    }
}

/// A job handed to the helper by [`Helper::start`], not yet waited for.
struct Pending<'h>(Option<&'h Helper>);

impl Pending<'_> {
    /// The job's answer.
    fn wait(mut self) -> Result<()> {
        self.0.take().map_or(Ok(()), |h| h.wait())
    }
}

impl Drop for Pending<'_> {
    fn drop(&mut self) {
        if let Some(h) = self.0.take() {
            let _ = h.wait();
        }
    }
}

impl Drop for Helper {
    fn drop(&mut self) {
        self.jobs = None; // ends the thread's loop
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Buffers of the row-streaming aggregation: the per-offset costs of the last WINDOW rows (a ring), their
/// column sums and the current row's box sums, a few tens of kilobytes that stay in cache (a whole-image
/// cost volume, OFFSETS x 2 bytes per pixel, does not).
struct RowWindow {
    w: usize,
    /// Raw costs: ring slot s holds OFFSETS rows of w costs.
    ring: Vec<u8>,
    /// Column sums per offset, with WINDOW / 2 zeros either side of each offset's w columns.
    col: Vec<i16>,
    /// Box sums of the current row per offset (at most WINDOW^2 x 24 = 1176: i16, whose compares are
    /// single SIMD instructions, unlike u16's).
    sum: Vec<i16>,
}

impl RowWindow {
    fn new(w: usize) -> RowWindow {
        RowWindow {
            w,
            ring: vec![0; WINDOW * OFFSETS * w],
            col: vec![0; OFFSETS * (w + WINDOW - 1)],
            sum: vec![0; OFFSETS * w],
        }
    }
}

impl CensusRefineEngine {
    /// The network `net` refined at `width` x `height` (any size; the network's input is resized).
    pub fn new(net: OnnxEngine, width: u32, height: u32) -> Result<CensusRefineEngine> {
        if width < WINDOW as u32 || height < WINDOW as u32 {
            return Err(DisparityError::Invalid(format!("census-refine: {width}x{height} is too small")));
        }
        let (mw, mh) = net.size();
        let (n, m) = ((width * height) as usize, (mw * mh) as usize);
        let resized = (mw, mh) != (width, height);
        let coarse = width > mw && mw as usize >= WINDOW && mh as usize >= WINDOW;
        let fine = !coarse || width as f64 > FINE_ABOVE * mw as f64;
        // the prior's range: the network's and 8 px, in OpenCV's steps of 16, below the network's width
        let range = ((net.max_disparity().ceil() as i32 + 8 + 15) / 16) * 16;
        let sgbm = (coarse && range + 16 <= mw as i32)
            .then(|| SgbmEngine::with_block(mw, mh, range as f64, PRIOR_BLOCK))
            .transpose()?;
        // the confidence comes from the last pass: the coarse one unless a pass at the engine's resolution runs
        let scored = if fine { (width as usize, height as usize) } else { (mw as usize, mh as usize) };
        let scored_here = scored != (width as usize, height as usize);
        let widths: Vec<usize> =
            [(coarse, mw as usize), (fine, width as usize)].iter().filter(|(on, _)| *on).map(|(_, w)| *w).collect();
        let prior = sgbm.is_some();
        Ok(CensusRefineEngine {
            name: format!("census-refine:{}{}", net.manifest.variant, if sgbm.is_some() { "+sgbm" } else { "" }),
            net,
            size: (width, height),
            net_left: vec![0; if resized { m } else { 0 }],
            net_right: vec![0; if resized { m } else { 0 }],
            net_disp: vec![f32::NAN; if resized { m } else { 0 }],
            prior: prior.then(|| Prior { disp: vec![f32::NAN; m] }),
            coarse: coarse.then(|| (Pass::new(mw as usize, mh as usize), vec![f32::NAN; m])),
            fine: fine.then(|| Pass::new(width as usize, height as usize)),
            guess: vec![f32::NAN; if fine { n } else { 0 }],
            helper: Helper::new(&widths, sgbm)?,
            net_raw: vec![f32::NAN; if prior { m } else { 0 }],
            scorer: Scorer::new(scored.0, scored.1),
            conf_pass: vec![0.0; if scored_here { scored.0 * scored.1 } else { 0 }],
            why_pass: vec![0; if scored_here { scored.0 * scored.1 } else { 0 }],
            conf: vec![0.0; n],
            why: vec![0; n],
            cost: MatchCost::new((width as usize, height as usize), scored),
            // the matched rows' codes only (one per row of the scored grid)
            full_census: (!fine).then(|| [vec![0; width as usize * scored.1], vec![0; width as usize * scored.1]]),
            scoring: true,
        })
    }

    /// The last frame's inputs of the confidence at the network's resolution (left and right images, search
    /// outcome bytes, refined answer, the network's own answer, SGBM's accepted matches), where the engine
    /// runs a prior: for fitting the confidence (disparity/examples/census_confidence_dump.rs).
    #[doc(hidden)]
    #[allow(clippy::type_complexity)]
    pub fn internals(&self) -> Option<(&[u8], &[u8], &[u8], &[f32], &[f32], &[f32])> {
        let (pass, refined) = self.coarse.as_ref()?;
        let prior = self.prior.as_ref()?;
        Some((&self.net_left, &self.net_right, &pass.stat, refined, &self.net_raw, &prior.disp))
    }

    /// The last frame's match cost on the scored grid ([`crate::match_cost`]), for fitting the confidence.
    #[doc(hidden)]
    pub fn match_cost(&self) -> &[f32] {
        self.cost.cost()
    }

    /// The last frame's match cost's curvature on the scored grid ([`crate::match_cost::Pooled::curv`]), for
    /// fitting the confidence.
    #[doc(hidden)]
    pub fn match_curvature(&self) -> &[f32] {
        self.cost.curvature()
    }

    /// The engine without its confidence ([`DisparityEngine::confidence`] gives none): the baseline of the
    /// confidence's cost (runtime/benches/pipeline.rs).
    pub fn without_confidence(mut self) -> Self {
        self.scoring = false;
        self
    }
}

impl DisparityEngine for CensusRefineEngine {
    fn name(&self) -> &str {
        &self.name
    }
    fn size(&self) -> (u32, u32) {
        self.size
    }
    fn max_disparity(&self) -> f64 {
        self.net.max_disparity() * self.size.0 as f64 / self.net.size().0 as f64
    }
    fn compute(&mut self, left: &[u8], right: &[u8], out: &mut [f32]) -> Result<()> {
        let (w, h) = (self.size.0 as usize, self.size.1 as usize);
        check_sizes(&self.name, self.size, left, right, out)?;
        let msize = self.net.size();
        let (mw, mh) = (msize.0 as usize, msize.1 as usize);
        if msize == self.size {
            // one pass at the engine's resolution: both censuses on the helper while the network runs
            let fine = self.fine.as_mut().ok_or_else(|| DisparityError::Invalid("census-refine: no pass".into()))?;
            self.helper.run(Job::Prepare { census: [Some(fine.census_job(left, right)), None], sgbm: None })?;
            let net = self.net.compute(left, right, &mut self.guess);
            self.helper.wait()?;
            net?;
            fine.refine(&self.helper, &self.guess, out)?;
            if self.scoring {
                self.scorer.score(left, &fine.stat, out, &self.guess, None, &mut self.conf, &mut self.why);
                Scorer::finish(&mut self.conf, self.cost.compute(Codes::Full(&fine.census_l, &fine.census_r), out));
            }
            return Ok(());
        }
        resize_gray(left, self.size, &mut self.net_left, msize)?;
        resize_gray(right, self.size, &mut self.net_right, msize)?;
        // everything that does not need the network on the helper while it runs: the censuses at the
        // network's resolution and the prior's SGBM; the engine's own census, if a second pass needs it,
        // here after the network when the prior keeps the helper busy
        let coarse = self.coarse.as_mut().map(|(p, _)| p.census_job(&self.net_left, &self.net_right));
        let sgbm =
            self.prior.as_mut().map(|p| ([self.net_left.as_ptr(), self.net_right.as_ptr()], p.disp.as_mut_ptr()));
        let fine_here = sgbm.is_some();
        let fine = match &mut self.fine {
            Some(f) if !fine_here => Some(f.census_job(left, right)),
            _ => None,
        };
        self.helper.run(Job::Prepare { census: [fine, coarse], sgbm })?;
        let net = self.net.compute(&self.net_left, &self.net_right, &mut self.net_disp);
        if let (Ok(()), true, Some(f)) = (&net, fine_here, &mut self.fine) {
            census(left, w, h, &mut f.census_l);
            census(right, w, h, &mut f.census_r);
        }
        self.helper.wait()?;
        net?;
        if let Some(p) = &self.prior {
            self.net_raw.copy_from_slice(&self.net_disp);
            for (n, &s) in self.net_disp.iter_mut().zip(&p.disp) {
                if s.is_finite() {
                    *n = s;
                }
            }
        }
        if let Some((pass, refined)) = &mut self.coarse {
            pass.refine(&self.helper, &self.net_disp, refined)?;
        }
        let answer: &[f32] = match &self.coarse {
            Some((_, refined)) => refined,
            None => &self.net_disp,
        };
        let net_raw = if self.prior.is_some() { &self.net_raw } else { &self.net_disp };
        match &mut self.fine {
            Some(fine) => {
                upsample_disparity(answer, (mw, mh), &mut self.guess, (w, h));
                fine.refine(&self.helper, &self.guess, out)?;
                if !self.scoring {
                    return Ok(());
                }
                // the network's own answer at this resolution is the guess only without a prior: with one,
                // the agreement is the coarse answer's (the guess) with the refined one
                self.scorer.score(left, &fine.stat, out, &self.guess, None, &mut self.conf, &mut self.why);
                Scorer::finish(&mut self.conf, self.cost.compute(Codes::Full(&fine.census_l, &fine.census_r), out));
            }
            None => {
                let stat: &[u8] = match &self.coarse {
                    Some((pass, _)) => &pass.stat[..],
                    None => &[],
                };
                let (Some([cl, cr]), true, false) = (&mut self.full_census, self.scoring, stat.is_empty()) else {
                    upsample_disparity(answer, (mw, mh), out, (w, h));
                    if self.scoring {
                        // no search ran (the network alone, resized): no evidence beyond its answer
                        self.conf.fill(0.0);
                        self.why.fill(reason::AMBIGUOUS);
                    }
                    return Ok(());
                };
                // the scoring, its reasons and the left census image's lower half (on the rows the cost uses) on
                // the helper (idle until the next frame) while the answer is upsampled here and the right census
                // image and the left one's upper half made: the two shares about even (the scoring is the
                // larger part; with the whole left image on the helper, its share was the frame's longest)
                let prior = self.prior.as_ref().map(|p| &p.disp[..]);
                let (scorer, net_left, cost) = (&mut self.scorer, &self.net_left, &self.cost);
                let (conf_pass, why_pass, why) = (&mut self.conf_pass, &mut self.why_pass, &mut self.why);
                let mid = cl.len() / w / 2;
                let (cl_top, cl_bottom) = cl.split_at_mut(mid * w);
                let mut side = || {
                    let lower = cost.rows().filter(|&(gy, _)| gy >= mid).map(|(gy, y)| (gy - mid, y));
                    census_rows(left, w, h, lower, cl_bottom);
                    scorer.score(net_left, stat, answer, net_raw, prior, conf_pass, why_pass);
                    // the reasons need no match cost
                    nearest(why_pass, (mw, mh), why, (w, h));
                };
                // SAFETY: `side` lives on this stack until the job is waited for (`Pending`, also on unwinding),
                // before anything it borrows is used here
                let pending = self.helper.start(Job::Call(unsafe { erase(&mut side) }))?;
                upsample_disparity(answer, (mw, mh), out, (w, h));
                census_rows(right, w, h, self.cost.rows(), cr);
                census_rows(left, w, h, self.cost.rows().filter(|&(gy, _)| gy < mid), cl_top);
                pending.wait()?;
                // the match cost's first step in halves, the lower on the helper
                let [top, bottom] = self.cost.halves(Codes::Rows(cl, cr), out);
                let mut bottom = Some(bottom);
                let mut lower = || {
                    if let Some(part) = bottom.take() {
                        part.run()
                    }
                };
                // SAFETY: as for `side`
                let pending = self.helper.start(Job::Call(unsafe { erase(&mut lower) }))?;
                top.run();
                pending.wait()?;
                Scorer::finish(&mut self.conf_pass, self.cost.finish());
                nearest(&self.conf_pass, (mw, mh), &mut self.conf, (w, h));
            }
        }
        Ok(())
    }
    fn confidence(&self) -> Option<(&[f32], &[u8])> {
        self.scoring.then_some((&self.conf[..], &self.why[..]))
    }
}

/// The centre of each pixel's search: its disparity rounded half away from zero, without a libm call (NaN: a
/// search around 0, whose answer is never used).
fn round_into(d: &[f32], base: &mut [i32]) {
    for (b, g) in base.iter_mut().zip(d) {
        *b = if g.is_finite() { (g.abs() + 0.5) as i32 * if *g < 0.0 { -1 } else { 1 } } else { 0 };
    }
}

/// The refinement, streamed down the rows: each row's costs at every offset are computed once, enter the
/// column sums WINDOW / 2 rows ahead and leave them WINDOW / 2 + 1 rows behind; each output row's box sums
/// are WINDOW shifted adds of the column sums, and its winner is taken at once. The box is clipped at the
/// image's border, for every offset alike, so the comparison between offsets stays fair.
///
/// Rows `ys` of the refinement (of an image of `h` rows) into `out`, those rows' disparities.
#[allow(clippy::too_many_arguments)]
fn refine(
    cl: &[u32],
    cr: &[u32],
    base: &[i32],
    guess: &[f32],
    h: usize,
    ys: Range<usize>,
    win: &mut RowWindow,
    out: &mut [f32],
    stat: &mut [u8],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("popcnt") {
        // SAFETY: the CPU has the instruction sets the function is compiled for (checked just above).
        unsafe { refine_avx2(cl, cr, base, guess, h, ys, win, out, stat) };
        return;
    }
    refine_generic(cl, cr, base, guess, h, ys, win, out, stat)
}

/// [`refine`] compiled for AVX2 (16 costs per instruction instead of SSE2's 8; the baseline x86-64 target
/// has only SSE2).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt")]
#[allow(clippy::too_many_arguments)]
unsafe fn refine_avx2(
    cl: &[u32],
    cr: &[u32],
    base: &[i32],
    guess: &[f32],
    h: usize,
    ys: Range<usize>,
    win: &mut RowWindow,
    out: &mut [f32],
    stat: &mut [u8],
) {
    refine_generic(cl, cr, base, guess, h, ys, win, out, stat)
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn refine_generic(
    cl: &[u32],
    cr: &[u32],
    base: &[i32],
    guess: &[f32],
    h: usize,
    ys: Range<usize>,
    win: &mut RowWindow,
    out: &mut [f32],
    stat: &mut [u8],
) {
    let (w, r) = (win.w, WINDOW / 2);
    let cw = w + 2 * r;
    win.col.fill(0);
    // the window of the first row: rows first - r ..= first + r - 1 (clipped) in, the loop adds first + r
    for y in ys.start.saturating_sub(r)..(ys.start + r).min(h) {
        update(cl, cr, base, win, y, true);
    }
    for y in ys.clone() {
        // the row leaving the window shares its ring slot with the row entering it: out first
        if y > r && y - r > ys.start.saturating_sub(r) {
            update(cl, cr, base, win, y - r - 1, false);
        }
        if y + r < h {
            update(cl, cr, base, win, y + r, true);
        }
        for o in 0..OFFSETS {
            let col = &win.col[o * cw..(o + 1) * cw];
            let sum = &mut win.sum[o * w..(o + 1) * w];
            sum.copy_from_slice(&col[..w]);
            for k in 1..WINDOW {
                for (a, &c) in sum.iter_mut().zip(&col[k..k + w]) {
                    *a += c;
                }
            }
        }
        let row = y * w..(y + 1) * w;
        let o = (y - ys.start) * w;
        winner(&win.sum, &base[row.clone()], &guess[row], &mut out[o..o + w], &mut stat[o..o + w]);
    }
}

/// A pixel's search outcome in a byte: the winner's margin over the best offset beyond its neighbours,
/// `(second - best) / second` in 1/[`MARGIN_ONE`] steps (0 ..= 127), and [`AT_EDGE`] when the winner is an
/// end of the search window (the true match may lie beyond it).
#[inline(always)]
fn search_stat(best: i16, second: i16, arg: i16) -> u8 {
    let (b, s) = (best.max(0) as u32, second.max(1) as u32);
    let m = (s.saturating_sub(b) * MARGIN_ONE / s).min(MARGIN_ONE) as u8;
    m | if arg == 0 || arg as usize == OFFSETS - 1 { AT_EDGE } else { 0 }
}

/// 5x5 census code of every pixel (bit set where the neighbour is darker than the centre), the image's
/// border replicated.
pub fn census(img: &[u8], w: usize, h: usize, out: &mut [u32]) {
    census_rows(img, w, h, (0..h).map(|y| (y, y)), out)
}

/// [`census`] of some rows only: for each `(k, y)`, image row `y`'s codes into row `k` of `out` (`w` wide).
pub fn census_rows(img: &[u8], w: usize, h: usize, rows: impl Iterator<Item = (usize, usize)>, out: &mut [u32]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has the instruction set the function is compiled for (checked just above).
        unsafe { census_avx2(img, w, h, rows, out) };
        return;
    }
    census_generic(img, w, h, rows, out)
}

/// [`census_generic`] with the interior 32 pixels at a time, the three bytes of their codes kept in registers
/// across the 24 neighbours (one load, compare, and and or each) and widened to the codes once, instead of byte
/// planes in memory: the confidence's added work (issue 41, disparity/examples/confidence_cost.rs) fell from 2.6
/// to 1.7-1.9 ms with it. AVX2 compares bytes as signed numbers only: both sides are offset by 128, which orders
/// them as unsigned. The same codes, bit for bit.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn census_avx2(img: &[u8], w: usize, h: usize, rows: impl Iterator<Item = (usize, usize)>, out: &mut [u32]) {
    use std::arch::x86_64::*;
    const V: usize = 32;
    let r = CENSUS_R;
    // the interior: columns whose whole window lies in the image
    let (lo, hi) = (r, w.saturating_sub(r));
    if hi < lo + V {
        return census_generic(img, w, h, rows, out);
    }
    // the neighbours below are written out for the 5x5 window
    const { assert!(CENSUS_R == 2) };
    let flip = _mm256_set1_epi8(i8::MIN);
    for (k, y) in rows {
        let code = &mut out[k * w..(k + 1) * w];
        let nbs: [*const u8; 2 * CENSUS_R + 1] = std::array::from_fn(|i| {
            let yy = (y + i).saturating_sub(r).min(h - 1);
            img[yy * w..(yy + 1) * w].as_ptr()
        });
        let mut x = lo;
        loop {
            // the last block overlaps the one before (the same codes again) rather than leaving a tail
            let x0 = x.min(hi - V);
            let c = _mm256_xor_si256(_mm256_loadu_si256(nbs[r].add(x0) as *const __m256i), flip);
            // neighbour (row, column) of the window into bit `bit` of `plane`, written out so that the planes stay
            // in registers (as loops the compiler kept them on the stack)
            let (mut p0, mut p1, mut p2) = (_mm256_setzero_si256(), _mm256_setzero_si256(), _mm256_setzero_si256());
            macro_rules! nb {
                ($plane:ident, $row:literal, $dx:literal, $bit:literal) => {
                    // SAFETY: x0 - r + dx + V <= hi - r + 2r = w (x0 >= lo = r): inside the row
                    let q = _mm256_loadu_si256(nbs[$row].add(x0 + $dx - r) as *const __m256i);
                    let m = _mm256_cmpgt_epi8(c, _mm256_xor_si256(q, flip));
                    $plane = _mm256_or_si256($plane, _mm256_and_si256(m, _mm256_set1_epi8((1u8 << $bit) as i8)));
                };
            }
            nb!(p0, 0, 0, 0);
            nb!(p0, 0, 1, 1);
            nb!(p0, 0, 2, 2);
            nb!(p0, 0, 3, 3);
            nb!(p0, 0, 4, 4);
            nb!(p0, 1, 0, 5);
            nb!(p0, 1, 1, 6);
            nb!(p0, 1, 2, 7);
            nb!(p1, 1, 3, 0);
            nb!(p1, 1, 4, 1);
            nb!(p1, 2, 0, 2);
            nb!(p1, 2, 1, 3);
            nb!(p1, 2, 3, 4);
            nb!(p1, 2, 4, 5);
            nb!(p1, 3, 0, 6);
            nb!(p1, 3, 1, 7);
            nb!(p2, 3, 2, 0);
            nb!(p2, 3, 3, 1);
            nb!(p2, 3, 4, 2);
            nb!(p2, 4, 0, 3);
            nb!(p2, 4, 1, 4);
            nb!(p2, 4, 2, 5);
            nb!(p2, 4, 3, 6);
            nb!(p2, 4, 4, 7);
            let planes = [p0, p1, p2];
            // widen: each 8 bytes of the three planes into 8 codes
            let halves = |p: __m256i| [_mm256_castsi256_si128(p), _mm256_extracti128_si256::<1>(p)];
            let [p0, p1, p2] = [halves(planes[0]), halves(planes[1]), halves(planes[2])];
            for j in 0..4 {
                let part = |p: [__m128i; 2]| {
                    let q = p[j / 2];
                    _mm256_cvtepu8_epi32(if j % 2 == 0 { q } else { _mm_srli_si128::<8>(q) })
                };
                let v = _mm256_or_si256(
                    part(p0),
                    _mm256_or_si256(_mm256_slli_epi32::<8>(part(p1)), _mm256_slli_epi32::<16>(part(p2))),
                );
                _mm256_storeu_si256(code.as_mut_ptr().add(x0 + 8 * j) as *mut __m256i, v);
            }
            x += V;
            if x >= hi {
                break;
            }
        }
        // the border columns, their neighbours clamped into the image
        let centre = std::slice::from_raw_parts(nbs[r], w);
        let nbs: [&[u8]; 2 * CENSUS_R + 1] = nbs.map(|p| std::slice::from_raw_parts(p, w));
        for x in (0..lo).chain(hi..w) {
            code[x] = census_at(&nbs, centre, x, w);
        }
    }
}

/// The census code of column `x` from its window's rows `nbs`, the neighbours clamped into the row.
#[inline(always)]
fn census_at(nbs: &[&[u8]; 2 * CENSUS_R + 1], centre: &[u8], x: usize, w: usize) -> u32 {
    let r = CENSUS_R as isize;
    let mut v = 0u32;
    let mut bit = 0u32;
    for (k, nb) in nbs.iter().enumerate() {
        for dx in -r..=r {
            if k == CENSUS_R && dx == 0 {
                continue;
            }
            let xx = (x as isize + dx).clamp(0, w as isize - 1) as usize;
            v |= ((nb[xx] < centre[x]) as u32) << bit;
            bit += 1;
        }
    }
    v
}

#[inline(always)]
fn census_generic(img: &[u8], w: usize, h: usize, rows: impl Iterator<Item = (usize, usize)>, out: &mut [u32]) {
    let r = CENSUS_R as isize;
    // Pixels in chunks of CHUNK, each code built as three bytes (8 neighbours each) and packed at the end:
    // the compares and ors run on bytes, four times as many per vector as on the u32 codes. Long chunks (1.5 kB
    // of planes on the stack): with 64 the loop's setup per neighbour cost more than its compares.
    const CHUNK: usize = 512;
    let (lo, hi) = (CENSUS_R.min(w), w.saturating_sub(CENSUS_R).max(CENSUS_R.min(w)));
    for (k, y) in rows {
        let code = &mut out[k * w..(k + 1) * w];
        let centre = &img[y * w..(y + 1) * w];
        let nbs: [&[u8]; 2 * CENSUS_R + 1] = std::array::from_fn(|k| {
            let yy = (y as isize + k as isize - r).clamp(0, h as isize - 1) as usize;
            &img[yy * w..(yy + 1) * w]
        });
        // the interior: contiguous slices the compiler vectorises
        let mut x0 = lo;
        while x0 < hi {
            let n = CHUNK.min(hi - x0);
            let mut planes = [[0u8; CHUNK]; 3];
            let c = &centre[x0..x0 + n];
            let mut bit = 0usize;
            for (k, nb) in nbs.iter().enumerate() {
                for dx in -r..=r {
                    if k == CENSUS_R && dx == 0 {
                        continue;
                    }
                    let s = (x0 as isize + dx) as usize;
                    let q = &nb[s..s + n];
                    let plane = &mut planes[bit / 8][..n];
                    let one = 1u8 << (bit % 8);
                    // a compare's all-ones byte masked to the bit (AVX2 has no per-byte shift)
                    for ((o, &p), &v) in plane.iter_mut().zip(c).zip(q) {
                        *o |= ((v < p) as u8).wrapping_neg() & one;
                    }
                    bit += 1;
                }
            }
            for (i, o) in code[x0..x0 + n].iter_mut().enumerate() {
                *o = planes[0][i] as u32 | (planes[1][i] as u32) << 8 | (planes[2][i] as u32) << 16;
            }
            x0 += n;
        }
        // the border columns, their neighbours clamped into the image
        for x in (0..lo).chain(hi..w) {
            code[x] = census_at(&nbs, centre, x, w);
        }
    }
}

/// Row y's costs at every offset: computed into its ring slot and added to the column sums (`enter`), or
/// taken out of them from the slot. (A function, not a closure: it is inlined into the AVX2 build.)
#[inline(always)]
fn update(cl: &[u32], cr: &[u32], base: &[i32], win: &mut RowWindow, y: usize, enter: bool) {
    let (w, r) = (win.w, WINDOW / 2);
    let cw = w + 2 * r;
    let slot = (y % WINDOW) * OFFSETS * w;
    let ring = &mut win.ring[slot..slot + OFFSETS * w];
    if enter {
        let row = y * w..(y + 1) * w;
        costs(&cl[row.clone()], &cr[row.clone()], &base[row], ring);
    }
    for (o, raw) in ring.chunks_exact(w).enumerate() {
        let col = &mut win.col[o * cw + r..o * cw + r + w];
        if enter {
            for (c, &v) in col.iter_mut().zip(raw) {
                *c += v as i16;
            }
        } else {
            for (c, &v) in col.iter_mut().zip(raw) {
                *c -= v as i16;
            }
        }
    }
}

/// Hamming costs of each left pixel of a row against the right pixels `base + offset` to its left, for every
/// offset (`raw`: OFFSETS rows). A pixel's right candidates are contiguous, read once for all offsets.
#[inline(always)]
fn costs(cl: &[u32], cr: &[u32], base: &[i32], raw: &mut [u8]) {
    let w = cl.len();
    for (x, (&l, &b)) in cl.iter().zip(base).enumerate() {
        // offset o (index k = o + SEARCH_PX) matches right pixel x - b - o: from x - b + SEARCH_PX down
        let first = x as i32 - b - SEARCH_PX;
        if first >= 0 && first as usize + OFFSETS <= w {
            let cand = &cr[first as usize..first as usize + OFFSETS];
            for k in 0..OFFSETS {
                raw[k * w + x] = (l ^ cand[OFFSETS - 1 - k]).count_ones() as u8;
            }
        } else {
            for k in 0..OFFSETS {
                let xr = first + (OFFSETS - 1 - k) as i32;
                raw[k * w + x] =
                    if xr >= 0 && (xr as usize) < w { (l ^ cr[xr as usize]).count_ones() as u8 } else { OUTSIDE };
            }
        }
    }
}

/// The best offset per pixel of a row (`agg`: OFFSETS planes of the row's box sums), with a parabola
/// through its neighbours' costs for the sub-pixel part.
#[inline(always)]
fn winner(agg: &[i16], base: &[i32], guess: &[f32], out: &mut [f32], stat: &mut [u8]) {
    let n = out.len();
    let planes: [&[i16]; OFFSETS] = std::array::from_fn(|k| &agg[k * n..(k + 1) * n]);
    // in chunks, one offset plane at a time: the minimum searches run across pixels (vectorised), not
    // across a pixel's strided planes
    const CHUNK: usize = 128;
    let (mut best, mut arg, mut second) = ([0i16; CHUNK], [0i16; CHUNK], [0i16; CHUNK]);
    for start in (0..n).step_by(CHUNK) {
        let len = CHUNK.min(n - start);
        let (best, arg, second) = (&mut best[..len], &mut arg[..len], &mut second[..len]);
        best.copy_from_slice(&planes[0][start..start + len]);
        arg.fill(0);
        for (k, plane) in planes.iter().enumerate().skip(1) {
            for ((b, a), &c) in best.iter_mut().zip(arg.iter_mut()).zip(&plane[start..start + len]) {
                let lower = c < *b;
                *b = if lower { c } else { *b };
                *a = if lower { k as i16 } else { *a };
            }
        }
        // the best offset beyond the winner's neighbours
        second.fill(i16::MAX);
        for (k, plane) in planes.iter().enumerate() {
            for ((s, &a), &c) in second.iter_mut().zip(arg.iter()).zip(&plane[start..start + len]) {
                let far = (k as i16 - a).abs() >= 2;
                *s = (*s).min(if far { c } else { i16::MAX });
            }
        }
        for j in 0..len {
            let i = start + j;
            let o = &mut out[i];
            if !guess[i].is_finite() {
                *o = f32::NAN;
                stat[i] = 0;
                continue;
            }
            stat[i] = search_stat(best[j], second[j], arg[j]);
            // a winner not clearly better than every offset beyond its neighbours is no evidence against
            // the network (flat or repetitive texture): the network's answer stays
            if (second[j] as u32) * 100 <= best[j] as u32 * (100 + UNIQUENESS_PCT) {
                *o = guess[i];
                continue;
            }
            let a = arg[j] as usize;
            let mut sub = 0.0;
            if a > 0 && a + 1 < OFFSETS {
                let (cm, cp, c0) = (planes[a - 1][i] as f32, planes[a + 1][i] as f32, best[j] as f32);
                let den = cm + cp - 2.0 * c0;
                if den > 0.0 {
                    sub = (cm - cp) / (2.0 * den);
                }
            }
            *o = (base[i] + a as i32 - SEARCH_PX) as f32 + sub;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn textured_pair(w: usize, h: usize, d: f32) -> (Vec<u32>, Vec<u32>) {
        // value noise: smooth enough for sub-pixel, textured enough for census
        let tex = |x: f32, y: usize| {
            let f = |x: f32| ((x * 0.37).sin() * 60.0 + (x * 0.113 + y as f32 * 0.71).cos() * 50.0) + 128.0;
            f(x).clamp(0.0, 255.0) as u8
        };
        let left: Vec<u8> = (0..w * h).map(|i| tex((i % w) as f32, i / w)).collect();
        let right: Vec<u8> = (0..w * h).map(|i| tex((i % w) as f32 + d, i / w)).collect();
        let (mut cl, mut cr) = (vec![0; w * h], vec![0; w * h]);
        census(&left, w, h, &mut cl);
        census(&right, w, h, &mut cr);
        (cl, cr)
    }

    /// A textured pair whose right view is the left shifted by `d` px: the search finds `d` from a guess up
    /// to SEARCH_PX off, sub-pixel included.
    #[test]
    fn refinement_finds_the_true_shift_from_a_guess_within_its_range() {
        let (w, h, d) = (96usize, 40usize, 7.5f32);
        let (cl, cr) = textured_pair(w, h, d);
        for guess in [d - 2.4, d, d + 2.6] {
            let g = vec![guess; w * h];
            let base: Vec<i32> = g.iter().map(|v| v.round() as i32).collect();
            let mut out = vec![0f32; w * h];
            refine(&cl, &cr, &base, &g, h, 0..h, &mut RowWindow::new(w), &mut out, &mut vec![0; w * h]);
            // away from the left band where the match leaves the right image
            let inner: Vec<f32> = (0..w * h).filter(|i| i % w >= 16 && i % w < w - 8).map(|i| out[i]).collect();
            let within = inner.iter().filter(|v| (**v - d).abs() <= 0.5).count() as f64 / inner.len() as f64;
            assert!(within > 0.95, "guess {guess}: {within} within 0.5 px");
        }
    }

    /// The streamed aggregation against the definition: per pixel and offset, the Hamming costs summed over
    /// the WINDOW x WINDOW box clipped at the border; the winner of those sums, with its uniqueness test and
    /// parabola, written out by brute force. Small, odd sizes and per-pixel guesses exercise the ring's
    /// wrap-around and the borders.
    /// The chunked byte-plane census equals the definition: bit k set where the k-th neighbour of the 5x5
    /// window (row-major, centre skipped) is darker than the centre, the border replicated; odd and tiny sizes.
    #[test]
    fn census_equals_the_definition() {
        for (w, h) in [(1usize, 1usize), (3, 2), (5, 5), (7, 3), (70, 9), (133, 6), (1100, 3)] {
            let img: Vec<u8> = (0..w * h).map(|i| ((i * 7919 + (i / 3) * 104_729) % 251) as u8).collect();
            let mut got = vec![0u32; w * h];
            census(&img, w, h, &mut got);
            for y in 0..h {
                for x in 0..w {
                    let (mut want, mut bit) = (0u32, 0);
                    for dy in -2isize..=2 {
                        for dx in -2isize..=2 {
                            if dy == 0 && dx == 0 {
                                continue;
                            }
                            let yy = (y as isize + dy).clamp(0, h as isize - 1) as usize;
                            let xx = (x as isize + dx).clamp(0, w as isize - 1) as usize;
                            want |= ((img[yy * w + xx] < img[y * w + x]) as u32) << bit;
                            bit += 1;
                        }
                    }
                    assert_eq!(got[y * w + x], want, "{w}x{h} at ({x}, {y})");
                }
            }
        }
    }

    /// The AVX2 census (where the CPU has it) gives the portable loop's codes: ties, the bytes either side of
    /// the signed compare's offset (127, 128) and the extremes, at widths around its 32-pixel blocks.
    #[test]
    fn the_vector_census_is_the_portable_one() {
        let mut seed = 5u32;
        let mut next = || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (seed >> 24) as u8
        };
        for (w, h) in [(36usize, 5usize), (37, 6), (67, 4), (68, 7), (640, 9)] {
            for palette in [&[0u8, 127, 128, 255][..], &[126, 127, 128, 129], &[]] {
                let img: Vec<u8> = (0..w * h)
                    .map(|_| if palette.is_empty() { next() } else { palette[next() as usize % palette.len()] })
                    .collect();
                let (mut fast, mut slow) = (vec![0u32; w * h], vec![0u32; w * h]);
                census(&img, w, h, &mut fast);
                census_generic(&img, w, h, (0..h).map(|y| (y, y)), &mut slow);
                assert_eq!(fast, slow, "{w}x{h}, palette {palette:?}");
            }
        }
    }

    /// Some rows into a compact buffer (output row k from image row y != k, as the match cost uses it): each
    /// written row equals the full image's row, and nothing else of the buffer is touched.
    #[test]
    fn census_rows_into_a_compact_buffer_equals_the_full_image() {
        for (w, h) in [(1usize, 1usize), (5, 5), (70, 9), (133, 6), (1100, 4)] {
            let img: Vec<u8> = (0..w * h).map(|i| ((i * 7919 + (i / 3) * 104_729) % 251) as u8).collect();
            let mut full = vec![0u32; w * h];
            census(&img, w, h, &mut full);
            // the last row of each pair of rows, and the first and last image rows out of order
            let rows: Vec<(usize, usize)> = (1..h).step_by(2).chain([0, h - 1]).enumerate().collect();
            let sentinel = 0xDEAD_BEEFu32;
            let mut got = vec![sentinel; w * (rows.len() + 1)];
            census_rows(&img, w, h, rows.iter().copied(), &mut got);
            for &(k, y) in &rows {
                assert_eq!(&got[k * w..(k + 1) * w], &full[y * w..(y + 1) * w], "{w}x{h}: row {y} into {k}");
            }
            assert!(got[rows.len() * w..].iter().all(|&v| v == sentinel), "{w}x{h}: wrote past its rows");
        }
    }

    #[test]
    fn streamed_refinement_equals_the_brute_force_definition() {
        for (w, h) in [(23usize, 17usize), (9, 8), (40, 5)] {
            let (cl, cr) = textured_pair(w, h, 3.3);
            let guess: Vec<f32> =
                (0..w * h).map(|i| if i % 29 == 5 { f32::NAN } else { 2.0 + (i % 7) as f32 * 0.4 }).collect();
            let base: Vec<i32> = guess.iter().map(|g| if g.is_finite() { g.round() as i32 } else { 0 }).collect();
            let mut out = vec![0f32; w * h];
            let mut stat = vec![0u8; w * h];
            refine(&cl, &cr, &base, &guess, h, 0..h, &mut RowWindow::new(w), &mut out, &mut stat);
            // the same rows refined in two parts (as the engine's two threads do)
            let mid = h / 2 + 1;
            let mut parts = vec![0f32; w * h];
            let (top, bottom) = parts.split_at_mut(mid * w);
            let mut stat2 = vec![0u8; w * h];
            let (st, sb) = stat2.split_at_mut(mid * w);
            refine(&cl, &cr, &base, &guess, h, 0..mid, &mut RowWindow::new(w), top, st);
            refine(&cl, &cr, &base, &guess, h, mid..h, &mut RowWindow::new(w), bottom, sb);
            assert_eq!(stat, stat2, "{w}x{h}: split search outcomes differ");
            for (a, b) in out.iter().zip(&parts) {
                assert!(a == b || (a.is_nan() && b.is_nan()), "{w}x{h}: split refinement differs");
            }
            let r = (WINDOW / 2) as isize;
            let cost = |x: isize, y: isize, o: i32| -> u32 {
                let i = y as usize * w + x as usize;
                let xr = x as i32 - base[i] - o;
                if xr >= 0 && (xr as usize) < w {
                    (cl[i] ^ cr[y as usize * w + xr as usize]).count_ones()
                } else {
                    OUTSIDE as u32
                }
            };
            for y in 0..h as isize {
                for x in 0..w as isize {
                    let i = y as usize * w + x as usize;
                    let agg: Vec<u32> = (0..OFFSETS as i32)
                        .map(|k| {
                            let mut s = 0;
                            for yy in (y - r).max(0)..=(y + r).min(h as isize - 1) {
                                for xx in (x - r).max(0)..=(x + r).min(w as isize - 1) {
                                    s += cost(xx, yy, k - SEARCH_PX);
                                }
                            }
                            s
                        })
                        .collect();
                    let a = (0..OFFSETS).min_by_key(|&k| (agg[k], k)).unwrap();
                    let second = (0..OFFSETS).filter(|k| k.abs_diff(a) >= 2).map(|k| agg[k]).min().unwrap();
                    let want = if !guess[i].is_finite() {
                        f32::NAN
                    } else if second * 100 <= agg[a] * (100 + UNIQUENESS_PCT) {
                        guess[i]
                    } else {
                        let mut sub = 0.0;
                        if a > 0 && a + 1 < OFFSETS {
                            let (cm, cp, c0) = (agg[a - 1] as f32, agg[a + 1] as f32, agg[a] as f32);
                            if cm + cp - 2.0 * c0 > 0.0 {
                                sub = (cm - cp) / (2.0 * (cm + cp - 2.0 * c0));
                            }
                        }
                        (base[i] + a as i32 - SEARCH_PX) as f32 + sub
                    };
                    assert!(
                        out[i] == want || (out[i].is_nan() && want.is_nan()),
                        "{w}x{h} ({x}, {y}): {} vs {want}",
                        out[i]
                    );
                    // the search's outcome byte, of the same sums
                    let want_stat =
                        if guess[i].is_finite() { search_stat(agg[a] as i16, second as i16, a as i16) } else { 0 };
                    assert_eq!(stat[i], want_stat, "{w}x{h} ({x}, {y})");
                }
            }
        }
    }
}
