from rosdeploy.cli import run

run()
