"""The disparity tests' shared cases: the region of interest the levers and the stages are matched over."""


ROI = [0.3, 0.25, 0.7, 0.75]
