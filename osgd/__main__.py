from osgd.cli import run

run()
