"""The execution layer: a plan executed on a robot that is not the model. The feedback policy that comes with a
plan, the state estimate from measurements, receding-horizon replanning from the measured state, the executor
that runs them, and a simulated robot whose world differs from the planner's model. ROS-free: the ROS layer
wires the executor and the simulated robot to topics and actions; the benchmarks run them in process."""
