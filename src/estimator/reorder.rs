//! Re-ordering of messages by stamp. (Implementation pending.)
