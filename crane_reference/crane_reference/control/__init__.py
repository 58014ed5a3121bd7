"""The actuated crane and its control: the plant (the crane of a config driven by joint torques, no
programmed constraints), the joint controller and the rigid feedforward, and the ROS-free core of the plant
node (commands checked and held per control period, the safe command on a timeout)."""
