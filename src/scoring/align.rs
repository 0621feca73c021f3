//! Scoring: align. (Implementation pending.)
