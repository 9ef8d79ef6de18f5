//! Headless LinuxCNC (filled in below).
