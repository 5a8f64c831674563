"""cito_ros: contact-implicit trajectory optimization for pushing, served over ROS 2.

The package is layered; a module imports only from its own layer and the layers below it:

    settings  typed, validated parameters (config/planner.yaml, config/scenes/*.yaml)
    model     the MuJoCo scene, the contact models, the simulator and its native plugins
    planner   the push problem, its derivatives, the solvers, the stages, evaluation, results
    ros       the thin ROS 2 layer: node, messages, markers, parameters, bags
    studies   benchmarks and studies that print measured figures, sweeps on Ray
    cli       the command-line tools
"""
