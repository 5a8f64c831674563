"""The model layer: the MuJoCo scene, the contact models behind one interface, the simulator, the
native engine plugins (model/native, the `_native` extension) and their Python oracle. ROS-free."""
