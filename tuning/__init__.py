"""uav_depth.tuning: the offline tuner. Imports the daemon's parameter schema and
disparity pipeline and scores exactly the function that flies."""
