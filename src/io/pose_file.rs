//! Pose file readers.
