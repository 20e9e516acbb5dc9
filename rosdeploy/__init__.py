"""rosdeploy: declarative deployment of ROS 2 software to robot fleets."""

__version__ = "0.1.0"
