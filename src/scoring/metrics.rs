//! Scoring: metrics. (Implementation pending.)
