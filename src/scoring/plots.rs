//! Scoring: plots. (Implementation pending.)
