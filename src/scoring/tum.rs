//! Scoring: tum. (Implementation pending.)
