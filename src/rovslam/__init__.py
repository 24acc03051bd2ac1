"""rovslam: vision-based SLAM for underwater ROVs (Caccia et al., LTOC sensor + EKF landmarks)."""

__version__ = "0.1.0"
