"""The studies layer: named cases, random pushes, benchmarks, studies and figures, each printing
measured figures; sweeps of solves on Ray. ROS-free."""
