//! Sensor model: wheel_odom. (Implementation pending.)
