//! sie — point-cloud registration with a self-tuning robust cost function: Statistical Inlier
//! Estimation (Ekekrantz, Folkesson, Jensfelt, "Adaptive Cost Function for Pointcloud
//! Registration").
pub mod sie;
