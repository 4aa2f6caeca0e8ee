//! The baselines under their own papers' protocols (issue 24): each paper's simulation
//! set-up rebuilt as the paper describes it, beside the paper's numbers.
pub mod drone;
pub mod iros;
pub mod report;
pub mod search;
