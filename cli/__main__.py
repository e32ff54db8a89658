from uav_depth.cli.main import entry

entry()
