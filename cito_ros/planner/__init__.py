"""The planner layer: the push task and problem, its derivatives, the solvers behind one interface, the
stages of both pipelines, the scripted starts, the evaluation of a plan and its results. ROS-free;
`planner.plan.plan_push` is the entry point."""
