//! The Extended Information Filter of the seed paper. (Implementation pending.)
