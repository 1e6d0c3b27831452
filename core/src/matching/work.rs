//! A round's work budget: what a robot's estimating may spend, counted as
//! it goes, so that a round's instructions are bounded by construction and
//! not only by what was measured.
//!
//! A robot that keeps driving estimates its peer every round on an
//! instruction budget (a board's: 3e8 a round). What a round spends
//! depends on the maps: a tracked round a few EM iterations, a round with
//! no fix a prior-free search and a placement or two refined for tens of
//! iterations each, and in the worst case five placements refined to
//! their last iteration. [`Work`] charges each step its cost before it is
//! taken (an EM iteration, a placement judged, a search's nodes), at
//! costs the caller gives ([`WorkCosts`]: fitted on the robot that runs
//! them), and refuses a step that would pass the limit. A refused step is
//! never an answer: EM cut short is not `Converged`, a placement not
//! judged is `NotConverged`, and no further placement of the round is
//! refined. Counts, not clocks: the same maps spend the same work on the
//! host's twin and on the board, so both still give the same answers.

/// What each step of a match costs, in instructions of the robot that runs
/// it (fitted on the boards' counts, docs/session.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WorkCosts {
    /// An EM iteration at the finest level (its whole sample of scene
    /// entries).
    pub fine_iteration: u32,
    /// An EM iteration at a coarser level.
    pub coarse_iteration: u32,
    /// A placement judged: the verdict's and the look-alike and hopeless
    /// checks' reads of the finest level, and what a refinement does once.
    pub placement: u32,
    /// A node of a prior-free search.
    pub global_node: u32,
    /// A node of a windowed search.
    pub window_node: u32,
}

impl WorkCosts {
    /// Nothing costs anything: [`Work::UNBOUNDED`]'s.
    pub const FREE: WorkCosts =
        WorkCosts { fine_iteration: 0, coarse_iteration: 0, placement: 0, global_node: 0, window_node: 0 };

    /// An EM iteration at `level` (0 the finest).
    pub fn iteration(&self, level: usize) -> u32 {
        if level == 0 {
            self.fine_iteration
        } else {
            self.coarse_iteration
        }
    }
}

/// A round's work meter: what is spent, of what may be.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Work {
    costs: WorkCosts,
    limit: u64,
    spent: u64,
    refused: bool,
}

impl Work {
    /// No limit and no costs (a host that is not on a budget): every step
    /// is taken, as without a meter.
    pub const UNBOUNDED: Work = Work { costs: WorkCosts::FREE, limit: u64::MAX, spent: 0, refused: false };

    /// A meter that lets the steps `costs` prices spend up to `limit`.
    pub const fn new(costs: WorkCosts, limit: u64) -> Self {
        Work { costs, limit, spent: 0, refused: false }
    }

    /// The costs it charges.
    pub fn costs(&self) -> &WorkCosts {
        &self.costs
    }

    /// What has been spent.
    pub fn spent(&self) -> u64 {
        self.spent
    }

    /// What may still be spent.
    pub fn left(&self) -> u64 {
        self.limit.saturating_sub(self.spent)
    }

    /// Whether a step was refused (the round's estimate was cut short).
    pub fn refused(&self) -> bool {
        self.refused
    }

    /// Takes a step of `cost`, if the limit allows it; `false` (and the
    /// meter says [`Work::refused`]) if not.
    pub(crate) fn take(&mut self, cost: u32) -> bool {
        let cost = u64::from(cost);
        if cost > self.left() {
            self.refused = true;
            return false;
        }
        self.spent += cost;
        true
    }

    /// Nodes of `cost` each that what is left pays for (all, when they
    /// cost nothing).
    pub(crate) fn nodes(&self, cost: u32) -> u32 {
        match self.left().checked_div(u64::from(cost)) {
            Some(n) => u32::try_from(n).unwrap_or(u32::MAX),
            None => u32::MAX,
        }
    }

    /// Charges `nodes` a search scored, `cost` each (a search capped at
    /// [`Work::nodes`] stays within the limit).
    pub(crate) fn charge_nodes(&mut self, nodes: u32, cost: u32) {
        self.spent = self.spent.saturating_add(u64::from(nodes) * u64::from(cost));
    }

    /// Marks the round cut short (a search that could not afford its nodes).
    pub(crate) fn refuse(&mut self) {
        self.refused = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const COSTS: WorkCosts =
        WorkCosts { fine_iteration: 10, coarse_iteration: 5, placement: 100, global_node: 2, window_node: 3 };

    #[test]
    fn a_step_is_taken_only_while_the_limit_allows_it() {
        let mut w = Work::new(COSTS, 118);
        assert!(w.take(COSTS.placement));
        assert!(w.take(COSTS.iteration(0)));
        assert!(!w.refused());
        assert!(!w.take(COSTS.iteration(0)), "120 would pass 118");
        assert!(w.refused());
        assert_eq!(w.spent(), 110);
        assert!(w.take(COSTS.iteration(1)), "a cheaper step still fits");
        assert_eq!((w.spent(), w.left()), (115, 3));
        assert_eq!(w.nodes(COSTS.window_node), 1);
        w.charge_nodes(1, COSTS.window_node);
        assert_eq!((w.left(), w.nodes(COSTS.global_node)), (0, 0));
    }

    #[test]
    fn the_unbounded_meter_refuses_nothing_and_counts_nothing() {
        let mut w = Work::UNBOUNDED;
        for _ in 0..1000 {
            assert!(w.take(w.costs().placement) && w.take(w.costs().iteration(0)));
        }
        assert_eq!(w.nodes(w.costs().global_node), u32::MAX);
        w.charge_nodes(u32::MAX, w.costs().window_node);
        assert_eq!((w.spent(), w.refused()), (0, false));
    }
}
