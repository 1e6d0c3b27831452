//! The relative pose of a peer, tracked round after round: prior-free until
//! the first fix the verdict accepts, then from the last fix (EM at the
//! finest level from it, [`Matcher::track_in`]), every answer through the
//! verdict; a fix that stops agreeing (the verdict says `NoOverlap` from
//! it, or EM does not settle from it or the answer is `Degenerate` twice
//! running) is withdrawn, and the next round searches again: the last
//! fix's window first (the robots meeting again, the transform between
//! their odometry frames moved only by the drift), then prior-free. An
//! unconfirmed fix that the peer's estimates refuse [`REFUSED_ROUNDS`]
//! running is dropped with its window: the next round is prior-free. Two
//! robots' estimates agree ([`agree`]) when they compose to about the
//! identity at both robots' places, so each robot judges a pair alike. A
//! robot without a fix may adopt its peer's ([`Tracker::adopt`]), judged
//! by its own verdict with a margin. A fix the robot's history of the
//! peer contradicts ([`History`]), or a first fix whose overlap stops
//! growing as the robots drive, is held but contested: not reported
//! `Converged` until its confirmed rounds outweigh that history, or its
//! overlap grows.
//!
//! A street seen along its length does not hold the match along it: from a
//! fix, that direction is held where the fix put it, for as long as the
//! robot has driven less than [`HOLD_M`] since the last fix the maps held
//! in every direction (beyond, the answer is `Degenerate`).

use super::history::{History, FIRST_GROWTH_M, FIRST_SEEN};
use super::smoother::Smoother;
use crate::geometry::{distance, Isometry3};
use crate::matching::search::SearchScratch;
use crate::matching::{
    align_prepared, Alignment, MatchError, MatchResult, MatchSettings, MatchStatus, Matcher, Pyramid, PyramidStorage,
    TrackStop,
};

/// How an estimate was made.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Kind {
    /// With no prior: every heading and offset searched.
    PriorFree,
    /// From the last fix: its window searched.
    Tracking,
}

impl Kind {
    /// The name reports use: `prior-free` or `tracking`.
    pub fn as_str(self) -> &'static str {
        match self {
            Kind::PriorFree => "prior-free",
            Kind::Tracking => "tracking",
        }
    }

    /// Its wire byte (a session robot's round report): 0 prior-free, 1
    /// tracking.
    pub fn code(self) -> u8 {
        self as u8
    }
}

/// What became of the fix this round.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Fix {
    /// No fix, none before.
    None,
    /// The estimate passed the verdict: it is the fix.
    Held,
    /// From the fix, EM did not settle (`NotConverged`) for the first time:
    /// no evidence against the fix, which stays for the next round.
    Kept,
    /// The fix stopped agreeing (the estimate from it failed the verdict):
    /// withdrawn; the next round searches prior-free.
    Withdrawn,
}

impl Fix {
    /// The name reports use: `none`, `held` or `withdrawn`.
    pub fn as_str(self) -> &'static str {
        match self {
            Fix::None => "none",
            Fix::Held => "held",
            Fix::Kept => "kept",
            Fix::Withdrawn => "withdrawn",
        }
    }

    /// Its wire byte: 0 none, 1 held, 2 kept, 3 withdrawn.
    pub fn code(self) -> u8 {
        self as u8
    }
}

/// Two robots' estimates of each other agree when they compose to within
/// this many metres of the identity where the robot is ...
///
/// The conventions' strict thresholds: a confirmed fix is reported
/// `Converged`, which claims that accuracy, so the two estimates must
/// agree to it. Both are made on the same two maps, so what they share
/// of their errors cancels in the loop and what is left is what differs
/// between them. At 1 m and 2 degrees (before) a prior-free fix 0.87 m
/// and 1.43 degrees off was confirmed by its peer's estimate 0.11 m and
/// 0.49 degrees off (camera labels, town seed 8): refused now, and found
/// right a round later.
pub const AGREE_M: f32 = 0.5;
/// ... and this many degrees.
pub const AGREE_DEG: f32 = 1.0;

/// How far (m) a robot may drive, since its last fix the maps held in
/// every direction, with the directions its maps do not constrain held at
/// that fix. The odometry's scale error moves them by about 1-2% of the
/// distance driven (the two robots' errors together): 10 m keep them
/// within 0.2-0.4 m, under the conventions' 0.5 m.
pub const HOLD_M: f32 = 10.0;

/// Rounds running an unconfirmed fix may disagree with the peer's estimate
/// (one that passed the peer's verdict) before it is dropped and the next
/// round searches prior-free. Why: a fix 1.5 m off along a street, found
/// on a copy a round behind, held by tracking for eight rounds while its
/// peer's right estimate refused it (town seed 2 over a 1% line); one of
/// the two is wrong, and only a new search can tell which. Two rounds: a
/// single disagreement is often a peer's estimate a round old.
pub const REFUSED_ROUNDS: u8 = 2;

/// How much more of what both maps saw standing must agree (the verdict's
/// least agreement raised by this) for a robot to adopt its peer's fix
/// ([`Tracker::adopt`]). Why: an adopted fix is not found by a second,
/// independent search, which is what keeps a look-alike out of
/// `Converged`; it is judged twice on one placement instead. With no
/// margin, a street turned by half a turn, 77-83 m off at no true overlap
/// (town seed 4, round 12), passed both robots' verdicts at agreements of
/// 0.41 and 0.43 and was reported `Converged`; the right adoptions of 24
/// two-robot, 12 three-robot and 6 camera-label sessions agreed 0.51-0.61.
pub const ADOPT_MARGIN: f32 = 0.10;

/// How much less of what both maps saw standing need agree (the verdict's
/// least agreement lowered by this) for a robot to adopt a fix its peer
/// reports `Converged` ([`Tracker::adopt`]: confirmed, and not contested
/// by the peer's history). Why: the margin above stands in for the
/// second, independent estimate an adopted fix lacks; a confirmed fix has
/// had it (two robots' estimates agreed, or the peer's recall of a fix it
/// had confirmed, [`Tracker::search`]), so this robot's verdict need only
/// say that the maps share the place under it. With a network's labels
/// the robot that did not find the fix sees less agreement under it than
/// its peer did: 0.38-0.49 for the 12 fixes so adopted at second meetings
/// (town seeds 1-24; all right), where the margin had asked 0.50 and
/// these rounds were lost. A contested fix is not enough: two searches do
/// find a look-alike alike (town seed 22, a street turned by half a turn
/// 35 m off, confirmed and contested, adopted at 0.35 with a slack of
/// 0.10). A peer's recall that this robot's own search found too is
/// adopted with it as well ([`adopt_backed`]).
pub const ADOPT_CONFIRMED_SLACK: f32 = 0.05;

/// What a robot knows of its peer's estimate of it, and where it is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PeerView {
    /// The peer's last estimate of `T_peer_own` that passed its verdict,
    /// if any.
    pub estimate: Option<Isometry3<f32>>,
    /// Where the robot is (its own frame): the agreement is judged there,
    /// not at the odometry origins, which drift puts a lever arm away.
    pub at: [f32; 3],
    /// Where the peer is (its own frame), if known: sent with its estimate,
    /// or as its copy's last cut said
    /// ([`crate::session::Replica::peer_place`]). The agreement is judged
    /// there too, so that both robots judge a pair of estimates alike.
    pub peer_at: Option<[f32; 3]>,
    /// Where the robot was when its copy of the peer's map last changed,
    /// if known. What the peer's map was a stretch of driving ago says
    /// little of where its odometry frame is now: under drift, a fix on
    /// it goes wrong as the robots part (over a 10% line, 0.6 m and 1-2
    /// degrees), so an estimate on a copy that has not changed for
    /// [`HOLD_M`] of driving is not reported `Converged`.
    pub copy_at: Option<[f32; 3]>,
    /// The two robots' odometry heading walk together, if known (degrees,
    /// [`crate::session::pair_walk`]): over
    /// [`crate::session::WALK_LIMIT_DEG`] no estimate is reported
    /// `Converged` ([`Estimate::walked`]).
    pub walk: Option<f32>,
}

/// One round's estimate of `T_own_peer`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Estimate {
    /// How it was made.
    pub kind: Kind,
    /// The match (own map the model, the peer's the scene).
    pub result: MatchResult,
    /// What became of the fix.
    pub fix: Fix,
    /// The fix agrees with the peer's estimate (now or since it was made).
    pub confirmed: bool,
    /// The fix contradicts the robot's history of the peer by more than
    /// drift explains, or is a first fix whose overlap stopped growing
    /// ([`History`]): held, not reported `Converged`.
    pub contested: bool,
    /// A first fix that explains no more of the peer's map than the robot's
    /// own estimates at its placement did in the rounds just before
    /// ([`crate::session::FIRST_SEEN`]): contested once confirmed, and not
    /// offered to the peer ([`Estimate::offered`]).
    pub doubted: bool,
    /// A confirmed fix the peer's latest estimate of this robot that passed
    /// its verdict disagrees with ([`agree`]): one of the two is wrong, and
    /// which the two robots cannot tell, so it is not reported `Converged`
    /// in that round (it is held and tracked).
    pub disputed: bool,
    /// The two robots' odometry walks more than
    /// [`crate::session::WALK_LIMIT_DEG`] ([`PeerView::walk`]): the maps
    /// may match, but their scans stray from them by about a degree, so
    /// no estimate is reported `Converged` (it is held and tracked).
    pub walked: bool,
}

impl Estimate {
    /// Whether the peer may hear it as this robot's fix, to confirm its own
    /// with or adopt: it passed the verdict and is not doubted. Why: two
    /// robots' searches can take one look-alike in the same round; when
    /// one robot's own estimates before it show it explaining less and
    /// less, that robot contests it, and its estimate must not confirm the
    /// other's (town seeds 25 and 43: a junction turned by 90 degrees and
    /// a street slid 55 m, reported `Converged` by the robot that had not
    /// seen them before).
    pub fn offered(&self) -> bool {
        self.result.status == MatchStatus::Converged && !self.doubted
    }

    /// The status reported: the match's, but `NotConverged` for a fix the
    /// peer's estimate has not agreed with yet, one contested, one the
    /// peer's estimate disputes, or any while the odometry walks too much.
    pub fn status(&self) -> MatchStatus {
        match self.result.status {
            MatchStatus::Converged if !self.confirmed || self.contested || self.disputed || self.walked => {
                MatchStatus::NotConverged
            }
            s => s,
        }
    }
}

/// Whether `ours` (`T_own_peer`) and the peer's `theirs` (`T_peer_own`)
/// compose to about the identity at `at` (the robot's place, its own
/// frame) and, when known, at `peer_at` (the peer's place, its frame) as
/// `ours` puts it.
///
/// Why both: the loop's rotation moves points in proportion to their
/// distance from where it is judged, and each robot judges at its own
/// place. Judged at one place only, two robots 40 m apart could each
/// decide differently about the same pair of estimates: over a line that
/// damages 10% of bytes (town seed 1, network labels) one robot's fix
/// 0.55 m off was confirmed at its place while its peer's, right, was
/// refused at the other's, dropped, and the wrong one reported
/// `Converged` for eight rounds.
pub fn agree(ours: &Isometry3<f32>, theirs: &Isometry3<f32>, at: [f32; 3], peer_at: Option<[f32; 3]>) -> bool {
    let loop_ = ours * theirs;
    let closes = |p: nalgebra::Point3<f32>| (loop_ * p - p).norm() < AGREE_M;
    let peer = peer_at.map(|q| ours * nalgebra::Point3::from(q));
    loop_.rotation.angle() < AGREE_DEG.to_radians() && closes(at.into()) && peer.is_none_or(closes)
}

/// Whether a robot adopts the peer's fix `theirs` (`T_peer_own`) with
/// [`ADOPT_CONFIRMED_SLACK`] rather than [`ADOPT_MARGIN`]
/// ([`Tracker::adopt`]'s `reported`): the peer reports it `Converged`
/// (`reported`), or it is the peer's recall of the fix the two confirmed
/// at a meeting before ([`Tracker::recalling`], `recalling`) and this
/// robot's own prior-free search of the round found it too (`own`: its
/// estimate's kind and `T_own_peer`, refused by its verdict), judged by
/// [`agree`] at `at` and `peer_at`.
///
/// Why: a recall and a second, independent search that finds the same
/// placement are what a confirmed fix is, less this robot's verdict, which
/// the adoption then asks at the slack. Town seed 5 (network labels, round
/// 111): the peer's recall 0.15 m off, this robot's search 0.19 m off at
/// agreement 0.39, refused; both waited a round.
pub fn adopt_backed(
    reported: bool,
    recalling: bool,
    own: Option<(Kind, &Isometry3<f32>)>,
    theirs: &Isometry3<f32>,
    at: [f32; 3],
    peer_at: Option<[f32; 3]>,
) -> bool {
    let found_too = own.is_some_and(|(kind, ours)| kind == Kind::PriorFree && agree(ours, theirs, at, peer_at));
    reported || (recalling && found_too)
}

/// Whether the peer's fix heard now was made in the peer's latest round,
/// the only fix a robot adopts ([`Tracker::adopt`]): the peer's estimate
/// heard the round before, `before` (one that passed its verdict), was
/// none.
///
/// Why not "unless it is the fix heard before": a peer that offered an
/// estimate the round before held a fix as its latest round began, and
/// that round's estimate is that fix tracked, or its window searched,
/// however far EM moved it. Judged by placement (the two agreeing), an
/// unconfirmed look-alike that slid 9.4 degrees and 4.7 m in one round
/// of tracking passed as new (camera labels, town seed 6, drift `1%,1`,
/// round 6: 81 m and 99 degrees off at no true overlap): adopted at
/// agreement 0.51, it confirmed both robots' fixes. Every right adoption
/// of the town's sessions (2 and 3 robots, true, network and camera
/// labels) was of a fix whose peer had offered nothing the round before.
pub fn made_this_round(before: Option<&Isometry3<f32>>) -> bool {
    before.is_none()
}

/// What tracking from the fix gave ([`Tracker::track`]): the round's
/// estimate, or what [`Tracker::search`] needs to finish the round.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tracked {
    done: Option<Estimate>,
    /// The answer from the fix, when it did not pass the verdict.
    answer: Option<MatchResult>,
}

impl Tracked {
    /// The round's estimate, when tracking from the fix made it.
    pub fn estimate(&self) -> Option<&Estimate> {
        self.done.as_ref()
    }
}

/// A robot's track of one peer: its last fix, if any, and the pose it
/// reports, smoothed over the fix's rounds ([`Smoother`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Tracker {
    /// The last answer that passed the verdict: tracking's next start.
    fix: Option<Isometry3<f32>>,
    /// The pose reported while the fix is held.
    smoothed: Option<Smoother>,
    /// Rounds running in which EM did not settle from the fix, or its
    /// answer was Degenerate.
    unsettled: u8,
    /// The fix has agreed with the peer's estimate.
    confirmed: bool,
    /// Where the robot was (its own frame) at the last fix the maps held in
    /// every direction: directions are held from it up to [`HOLD_M`].
    whole_at: Option<[f32; 3]>,
    /// The last fix held, kept when it is withdrawn: the transform between
    /// two odometry frames outlives a meeting.
    last: Option<Isometry3<f32>>,
    /// The last fix held (`last`) was confirmed by the peer.
    last_confirmed: bool,
    /// The fix is a recall of a fix the peer confirmed (`last_confirmed`),
    /// not yet vouched for: it is once it passes the verdict again
    /// ([`Tracker::vouch`]).
    vouch_pending: bool,
    /// Rounds running in which the fix, unconfirmed, disagreed with the
    /// peer's estimate that passed the peer's verdict.
    refused: u8,
    /// The confirmed fixes so far, which a new fix must be consistent
    /// with: kept when a fix is withdrawn or dropped.
    history: History,
    /// This round's estimate, whatever its status.
    seen: Option<Seen>,
    /// The round before's ([`History::confirmed_after`]).
    seen_before: Option<Seen>,
}

/// A round's estimate, passed or not: its placement, the most the
/// estimates at that placement explained of the peer's map, and where both
/// robots were.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Seen {
    transform: Isometry3<f32>,
    /// The most any estimate explained over the run of rounds, this one's
    /// included, whose estimates were at this placement one after another.
    most: f32,
    at: [f32; 3],
    peer_at: Option<[f32; 3]>,
}

impl Seen {
    /// This round's estimate, continuing the run of `before` when it was at
    /// the same placement.
    fn after(before: Option<&Seen>, result: &MatchResult, at: [f32; 3], peer_at: Option<[f32; 3]>) -> Self {
        let (transform, overlap) = (result.transform, result.overlap);
        let most = match before {
            Some(b) if b.same_placement(&transform, at) => b.most.max(overlap),
            _ => overlap,
        };
        Seen { transform, most, at, peer_at }
    }

    /// Whether `fix` is its placement ([`FIRST_SEEN`]), judged at the
    /// robot's place `at`.
    fn same_placement(&self, fix: &Isometry3<f32>, at: [f32; 3]) -> bool {
        let turn = (self.transform.inverse() * fix).rotation.angle();
        let here = fix.inverse() * nalgebra::Point3::from(at);
        let apart = (fix * here - self.transform * here).norm();
        turn <= FIRST_SEEN.1.to_radians() && apart <= FIRST_SEEN.0
    }

    /// The most its run explained of the peer's map, when `fix` is its
    /// placement and the robots have driven [`FIRST_GROWTH_M`] since.
    fn overlap_before(&self, fix: &Isometry3<f32>, at: [f32; 3], peer_at: Option<[f32; 3]>) -> Option<f32> {
        let driven = distance(self.at, at)
            + match (self.peer_at, peer_at) {
                (Some(a), Some(b)) => distance(a, b),
                _ => 0.0,
            };
        (self.same_placement(fix, at) && driven >= FIRST_GROWTH_M).then_some(self.most)
    }
}

impl Tracker {
    /// A track with no fix.
    pub const fn new() -> Self {
        Tracker {
            fix: None,
            smoothed: None,
            unsettled: 0,
            confirmed: false,
            whole_at: None,
            last: None,
            last_confirmed: false,
            vouch_pending: false,
            refused: 0,
            history: History::new(),
            seen: None,
            seen_before: None,
        }
    }

    /// The fix held (`T_own_peer`), if any: the last answer that passed
    /// the verdict, which the next round tracks from.
    pub fn fix(&self) -> Option<&Isometry3<f32>> {
        self.fix.as_ref()
    }

    /// Whether the fix held is a recall not yet vouched for: found again,
    /// this round or an earlier one, in the window of the last fix the
    /// peer confirmed ([`Tracker::search`]), and confirmed once it passes
    /// the verdict again or the peer's estimate agrees with it.
    pub fn recalling(&self) -> bool {
        self.vouch_pending && self.fix.is_some() && !self.confirmed
    }

    /// The pose reported while the fix is held: the fix's answers
    /// smoothed ([`Smoother`]).
    pub fn reported(&self) -> Option<&Isometry3<f32>> {
        self.smoothed.as_ref().map(Smoother::transform)
    }

    /// Forgets the fix, the last one held and the history (the peer
    /// restarted, or its map was resent whole; a one-shot exchange's every
    /// round).
    pub fn reset(&mut self) {
        *self = Tracker::new();
    }

    /// Withdraws the fix; the last one held is kept to be searched around
    /// when the robots meet again ([`Tracker::search`]), and the history.
    fn withdraw(&mut self) {
        // A recall not yet vouched for keeps the confirmation it recalled.
        let last_confirmed = match self.fix {
            Some(_) => self.confirmed || (self.vouch_pending && self.last_confirmed),
            None => self.last_confirmed,
        };
        let (last, history, seen, seen_before) = (self.last, self.history, self.seen, self.seen_before);
        *self = Tracker { last, last_confirmed, history, seen, seen_before, ..Tracker::new() };
    }

    /// Drops the fix with its window; the history is kept.
    fn drop_fix(&mut self) {
        let (history, seen, seen_before) = (self.history, self.seen, self.seen_before);
        *self = Tracker { history, seen, seen_before, ..Tracker::new() };
    }

    /// The robot's history of the peer's pose: the confirmed fixes a new
    /// one must be consistent with.
    pub fn history(&self) -> &History {
        &self.history
    }

    /// The last fix held, kept when it was withdrawn (until
    /// [`Tracker::reset`]).
    pub fn last(&self) -> Option<&Isometry3<f32>> {
        self.last.as_ref()
    }

    /// `result` as reported: Converged with what the maps leave free held
    /// at the fix only up to [`HOLD_M`] from where the last whole fix was
    /// made (beyond: Degenerate); a whole answer moves that place here.
    fn limit_hold(&mut self, mut result: MatchResult, how: &Alignment, view: &PeerView) -> MatchResult {
        if result.status == MatchStatus::Converged {
            if result.degeneracy >= how.settings.degeneracy_threshold {
                self.whole_at = Some(view.at);
            } else if self.whole_at.is_none_or(|w| distance(w, view.at) > HOLD_M) {
                // Held for too long: what the maps leave free has drifted.
                result.status = MatchStatus::Degenerate;
            }
        }
        result
    }

    /// A tracker holding `fix`, confirmed by the peer or not (tests).
    #[cfg(test)]
    pub(crate) fn holding(fix: Isometry3<f32>, confirmed: bool) -> Tracker {
        Tracker { fix: Some(fix), last: Some(fix), confirmed, ..Tracker::new() }
    }

    /// Where EM from the fix stops ([`Tracker::track`]): coarsely for a fix
    /// the peer has confirmed ([`TrackStop::Coarse`]), and where a match's
    /// EM does for one it has not ([`TrackStop::Fine`]).
    ///
    /// Why: an unconfirmed fix is a meeting's first answer, found on its
    /// first sliver of overlap and often a degree off (town seed 5, 3
    /// robots: 1.07 degrees). EM that stops on the coarse tolerances moved
    /// it one to three iterations a round and kept it off (1.06, 1.23,
    /// 1.46 degrees) while the peer's right answer could not confirm it;
    /// run to the match's tolerances it was right a round sooner. On
    /// held-out town seed 41 a recalled fix 1.4 degrees off, tracked so,
    /// came right a round sooner (wrong `Converged` 2 to 1), and the
    /// meeting's first fix from 4 rounds to 2. Such rounds are few (a
    /// meeting's first, and a look-alike's), so the tracking round's median
    /// cost is unchanged; a confirmed fix moves by a round's drift and
    /// keeps the coarse stop (measured in docs/session.md).
    fn tracking_stop(&self) -> TrackStop {
        if self.confirmed {
            TrackStop::Coarse
        } else {
            TrackStop::Fine
        }
    }

    /// This round's estimate: `own` (the model) against the peer's copy
    /// (`peer`, the scene), from the fix when one is held
    /// ([`Matcher::track_in`]), else prior-free ([`align_prepared`]), as
    /// `how` says; confirmed when it agrees with what `view` says of the
    /// peer's estimate. Both pyramids whole; [`Tracker::track`] then
    /// [`Tracker::search`] do the same with pyramids prepared for tracking
    /// first, and whole ones only when a search is needed.
    pub fn estimate<P: PyramidStorage, Q: PyramidStorage>(
        &mut self,
        own: &Pyramid<'_, P>,
        peer: &Pyramid<'_, Q>,
        how: &Alignment,
        scratch: &mut SearchScratch<'_>,
        view: &PeerView,
    ) -> Result<Estimate, MatchError> {
        let tracked = self.track(own, peer, how, scratch, view)?;
        self.search(own, peer, how, scratch, view, tracked)
    }

    /// This round's estimate from the fix, if one is held: EM at the finest
    /// level from it ([`Matcher::track_in`]), which reads only what a
    /// pyramid prepared for tracking holds ([`Pyramid::build_tracked`], or
    /// a whole one). An answer that passes the verdict is the round's
    /// estimate ([`Tracked::estimate`]); otherwise (no fix, or EM did not
    /// settle from it) [`Tracker::search`] finishes the round with whole
    /// pyramids. Of `scratch`, EM's room to remember blocks is used
    /// ([`SearchScratch::with_reach`]).
    pub fn track<P: PyramidStorage, Q: PyramidStorage>(
        &mut self,
        own: &Pyramid<'_, P>,
        peer: &Pyramid<'_, Q>,
        how: &Alignment,
        scratch: &mut SearchScratch<'_>,
        view: &PeerView,
    ) -> Result<Tracked, MatchError> {
        // A round begins: its estimate, once settled, is `seen`.
        self.seen_before = self.seen.take();
        let Some(fix) = self.fix else {
            return Ok(Tracked { done: None, answer: None });
        };
        let tracked = self.limit_hold(
            Matcher::new(how.settings).track_in(own, peer, &fix, self.tracking_stop(), scratch)?,
            how,
            view,
        );
        if tracked.status == MatchStatus::Converged {
            let mut done = self.settle(Kind::Tracking, tracked, view);
            self.vouch(&mut done, view);
            Ok(Tracked { done: Some(done), answer: None })
        } else {
            Ok(Tracked { done: None, answer: Some(tracked) })
        }
    }

    /// Finishes the round [`Tracker::track`] began: its estimate, if it
    /// made one; else, with whole pyramids, the fix's window searched (a
    /// prior-free fix a little off, a slip) and, when that fails too, the
    /// tracked answer; with no fix, the window of the last fix held, if
    /// any ([`Tracker::last`]), then the prior-free search.
    ///
    /// The transform between two robots' odometry frames outlives the
    /// meeting that found it: by the next meeting, anywhere in the town,
    /// only the drift has moved it, by metres and a degree or two, inside
    /// the window a prior-free candidate is refined in
    /// ([`crate::matching::search::GlobalSearch::refinement_window`]: 4 m and 6 degrees; the
    /// matcher's own, 15 m and 30 degrees, searched on maps that mostly
    /// share nothing in every round without a fix, added about 6% to a
    /// session's time). There
    /// the prior-free search often ranks a junction turned by 90 degrees or
    /// a street slid along itself first. A placement from the last fix's
    /// window is a tracking estimate, judged by the same verdict (and
    /// [`HOLD_M`]) and reported `Converged` once the peer's estimate
    /// agrees, or at once when the peer confirmed that last fix and its
    /// estimate does not disagree (`vouch`); one that fails leaves the round
    /// to the prior-free search.
    pub fn search<P: PyramidStorage, Q: PyramidStorage>(
        &mut self,
        own: &Pyramid<'_, P>,
        peer: &Pyramid<'_, Q>,
        how: &Alignment,
        scratch: &mut SearchScratch<'_>,
        view: &PeerView,
        tracked: Tracked,
    ) -> Result<Estimate, MatchError> {
        if let Some(done) = tracked.done {
            return Ok(done);
        }
        // A recalled fix the peer vouched for at the last meeting.
        let mut vouched = false;
        let (kind, result) = match (self.fix, tracked.answer) {
            (Some(fix), Some(tracked)) => {
                // The fix no longer explains the maps from where it is: its
                // window is searched before it is given up.
                let searched = align_prepared(own, peer, Some(&fix), how, scratch, || {})?.0;
                let result = if searched.status == MatchStatus::Converged {
                    self.limit_hold(searched, how, view)
                } else {
                    tracked
                };
                (Kind::Tracking, result)
            }
            // No fix (or it was withdrawn since): a new fix, if any, starts
            // unconfirmed.
            _ => {
                self.withdraw();
                match self.recall(own, peer, how, scratch, view)? {
                    Some(recalled) => {
                        vouched = self.last_confirmed;
                        (Kind::Tracking, recalled)
                    }
                    None => {
                        let found = align_prepared(own, peer, None, how, scratch, || {})?.0;
                        (Kind::PriorFree, self.limit_hold(found, how, view))
                    }
                }
            }
        };
        let mut estimate = self.settle(kind, result, view);
        if vouched {
            // Vouched for from the next round on, once it passes again.
            self.vouch_pending = estimate.fix == Fix::Held && !estimate.confirmed;
        } else {
            self.vouch(&mut estimate, view);
        }
        Ok(estimate)
    }

    /// The last fix's window searched ([`Tracker::search`]): the answer,
    /// when it passes the verdict and the hold's limit.
    fn recall<P: PyramidStorage, Q: PyramidStorage>(
        &mut self,
        own: &Pyramid<'_, P>,
        peer: &Pyramid<'_, Q>,
        how: &Alignment,
        scratch: &mut SearchScratch<'_>,
        view: &PeerView,
    ) -> Result<Option<MatchResult>, MatchError> {
        let Some(last) = self.last else { return Ok(None) };
        let window = how.search.refinement_window();
        let narrow = Alignment { settings: MatchSettings { search: Some(window), ..how.settings }, ..*how };
        let found = self.limit_hold(align_prepared(own, peer, Some(&last), &narrow, scratch, || {})?.0, how, view);
        Ok(Some(found).filter(|r| r.status == MatchStatus::Converged))
    }

    /// Confirms `estimate`, tracked from a fix found again in the window
    /// of the last fix the peer confirmed ([`Tracker::search`]'s recall)
    /// in an earlier round (`vouch_pending`), unless the peer's estimate
    /// disagrees: the peer confirmed that transform at the last meeting,
    /// and since only drift has moved it.
    ///
    /// Why: at a second meeting one robot's recall often finds the fix a
    /// round or two before the peer's does (its copy of the robot's map
    /// lags, or its own window falls short), and the fix waited,
    /// unconfirmed. On town seeds 1-24 (2 robots, true and network labels)
    /// 78 of 79 recalled fixes were right, and the other a drift near miss
    /// (0.57 m) that the peer confirmed a round later (docs/session.md).
    ///
    /// Not in the recall's own round: a recall at a meeting's first sliver
    /// of overlap can settle off. Held-out town seed 59 (network labels)
    /// had one 2.5 degrees and 0.7 m off, and town seed 5 (true labels,
    /// updates bounded to 15% of the map) one 1.7 degrees and 1.8 m off
    /// at a true overlap of 0.27, tracked to `NoOverlap` the next round.
    fn vouch(&mut self, estimate: &mut Estimate, view: &PeerView) {
        if !self.vouch_pending {
            return;
        }
        let r = &estimate.result;
        let passed = r.status == MatchStatus::Converged && self.fix.is_some();
        let refused = view.estimate.is_some_and(|theirs| !agree(&r.transform, &theirs, view.at, view.peer_at));
        if passed && !estimate.confirmed && !refused {
            self.confirm_now(estimate, view.at, view.peer_at);
        }
        self.vouch_pending &= !estimate.confirmed;
    }

    /// Confirms `estimate`'s fix now, after its round was settled: the
    /// history counts it as confirmed ([`Tracker::confirm`], `vouch`).
    fn confirm_now(&mut self, estimate: &mut Estimate, at: [f32; 3], peer_at: Option<[f32; 3]>) {
        self.confirmed = true;
        estimate.confirmed = true;
        let r = &estimate.result;
        let (fix, overlap, agreement) = (r.transform, r.overlap, r.agreement);
        let before = self.seen_before.and_then(|s| s.overlap_before(&fix, at, peer_at));
        estimate.contested = self.history.confirmed_after(&fix, overlap, agreement, (at, peer_at), before);
    }

    /// The fix after `result` (made from the fix for [`Kind::Tracking`]),
    /// and the estimate reported: an answer that passed the verdict is the
    /// next fix, and reports its pose smoothed with the fix's before it
    /// once the peer has confirmed the fix (a new or unconfirmed fix starts
    /// the smoothing again).
    fn settle(&mut self, kind: Kind, mut result: MatchResult, view: &PeerView) -> Estimate {
        let (at, peer_at) = (view.at, view.peer_at);
        self.seen = Some(Seen::after(self.seen_before.as_ref(), &result, at, peer_at));
        let fix = match (result.status, kind == Kind::Tracking) {
            (MatchStatus::Converged, _) => {
                let answer = result.transform;
                // Smoothed from the state of a fix the peer confirmed: an
                // unconfirmed fix's answers, on a meeting's first sliver of
                // overlap, are often off alike round after round, and a
                // state built on them held the first right answer back.
                let held = self.fix.is_some() && self.confirmed;
                result.transform = match self.smoothed.as_mut().filter(|_| held) {
                    Some(s) => s.update(answer, &result.information, view.at, view.walk),
                    None => {
                        self.smoothed = Some(Smoother::start(answer, &result.information, view.at));
                        answer
                    }
                };
                (self.fix, self.unsettled) = (Some(answer), 0);
                self.last = self.fix;
                Fix::Held
            }
            // A street seen along its length is Degenerate for a round or
            // two (nothing holds the match along it) while the fix is still
            // right: kept once, as an answer that did not settle.
            (MatchStatus::NotConverged | MatchStatus::Degenerate, true) if self.unsettled == 0 => {
                self.unsettled = 1;
                Fix::Kept
            }
            (_, true) => {
                self.withdraw();
                Fix::Withdrawn
            }
            (_, false) => Fix::None,
        };
        let converged = result.status == MatchStatus::Converged;
        if converged && view.estimate.is_some_and(|theirs| agree(&result.transform, &theirs, view.at, view.peer_at)) {
            self.confirmed = true;
        }
        // An unconfirmed fix the peer's own estimate keeps refusing is
        // dropped, and not recalled: a fix that passes the verdict is
        // tracked, not searched again, for as long as it keeps passing.
        let refused = converged && !self.confirmed && view.estimate.is_some();
        self.refused = if refused { self.refused.saturating_add(1) } else { 0 };
        let fix = if self.refused >= REFUSED_ROUNDS {
            self.drop_fix();
            Fix::Withdrawn
        } else {
            fix
        };
        if converged && view.copy_at.is_some_and(|p| distance(p, view.at) > HOLD_M) {
            result.status = MatchStatus::NotConverged;
        }
        self.history.drive(view.at, view.peer_at);
        let confirmed = converged && self.confirmed;
        let before = self.seen_before.and_then(|s| s.overlap_before(&result.transform, at, peer_at));
        let r = &result;
        let doubted = converged && self.history.doubts(&r.transform, r.overlap, r.agreement, (at, peer_at), before);
        // A round counts in the history when it is reported: an estimate on
        // a stale copy is not.
        let contested = converged
            && if confirmed && r.status == MatchStatus::Converged {
                self.history.confirmed_after(&r.transform, r.overlap, r.agreement, (at, peer_at), before)
            } else {
                self.history.contests(&r.transform, at, peer_at)
            };
        let disputed = confirmed && view.estimate.is_some_and(|t| !agree(&r.transform, &t, at, peer_at));
        let walked = converged && view.walk.is_some_and(|w| w > crate::session::WALK_LIMIT_DEG);
        Estimate { kind, result, fix, confirmed, contested, doubted, disputed, walked }
    }

    /// Adopts the peer's fix of this round, `theirs` (`T_peer_own`: one that
    /// passed the peer's verdict and that no estimate of this robot has
    /// agreed with), when this robot holds no fix: EM from its inverse (the
    /// tracking path, [`Matcher::track_in`]) and this robot's verdict with
    /// the least agreement raised by [`ADOPT_MARGIN`], or, when the peer
    /// reports its fix `Converged` (`reported`: confirmed, not contested),
    /// lowered by [`ADOPT_CONFIRMED_SLACK`]. An answer that passes and
    /// agrees with `theirs` ([`agree`] at `view`'s places) is this
    /// robot's fix, confirmed (`view.estimate` is ignored: `theirs` is
    /// the peer's estimate heard); the caller confirms the peer's fix with
    /// it ([`Tracker::confirm`]). `None`: not adopted, the track as it was.
    /// Callers adopt only a fix the peer made in this round
    /// ([`made_this_round`]): one the peer held for rounds while this
    /// robot's own searches did not find it was a street slid 112 m (town
    /// seed 19), adopted at agreement 0.50.
    ///
    /// Why: in a meeting's first rounds one robot's search often finds the
    /// placement while the other's ranks a junction turned by 90 degrees or
    /// a street slid along itself first; the first robot's fix waited,
    /// unconfirmed, until the second found it on its own, a round or more
    /// later (town, network labels, seeds 1-12: 25 of the 39 triples the
    /// meetings lost).
    pub fn adopt<P: PyramidStorage, Q: PyramidStorage>(
        &mut self,
        (own, peer): (&Pyramid<'_, P>, &Pyramid<'_, Q>),
        how: &Alignment,
        scratch: &mut SearchScratch<'_>,
        view: &PeerView,
        theirs: &Isometry3<f32>,
        reported: bool,
    ) -> Result<Option<Estimate>, MatchError> {
        if self.fix.is_some() {
            return Ok(None);
        }
        let margin = if reported { -ADOPT_CONFIRMED_SLACK } else { ADOPT_MARGIN };
        let strict = MatchSettings { min_agreement: how.settings.min_agreement + margin, ..how.settings };
        let answer = Matcher::new(strict).track_in(own, peer, &theirs.inverse(), TrackStop::Coarse, scratch)?;
        let before = *self;
        let answer = self.limit_hold(answer, how, view);
        if answer.status != MatchStatus::Converged || !agree(&answer.transform, theirs, view.at, view.peer_at) {
            *self = before;
            return Ok(None);
        }
        let heard = PeerView { estimate: Some(*theirs), ..*view };
        Ok(Some(self.settle(Kind::Tracking, answer, &heard)))
    }

    /// Confirms this round's fix (`estimate`, updated) with the peer's
    /// estimate of the same round, `theirs` (`T_peer_own`, one that passed
    /// the peer's verdict), heard once both have estimated: a robot that
    /// answers a peer's update after its own estimate can carry that
    /// estimate in the answer, so a fix both find in one round is reported
    /// in that round, not the next. The same test as [`Tracker::estimate`]'s
    /// ([`agree`] at `at` and `peer_at`).
    pub fn confirm(
        &mut self,
        estimate: &mut Estimate,
        theirs: &Isometry3<f32>,
        at: [f32; 3],
        peer_at: Option<[f32; 3]>,
    ) {
        let current =
            estimate.result.status == MatchStatus::Converged && self.reported() == Some(&estimate.result.transform);
        if !current {
            return;
        }
        let agreed = agree(&estimate.result.transform, theirs, at, peer_at);
        // The peer's estimate of this round, not the last's, says whether
        // the two dispute.
        estimate.disputed = estimate.confirmed && !agreed;
        if agreed && !estimate.confirmed {
            self.confirm_now(estimate, at, peer_at);
        }
    }
}
