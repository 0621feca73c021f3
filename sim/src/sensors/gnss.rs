//! Sensor model: gnss. (Implementation pending.)
