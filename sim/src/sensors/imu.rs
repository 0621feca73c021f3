//! Sensor model: imu. (Implementation pending.)
