# Sourced, from the repository root, by a script that runs on a lent GPU machine (`source gpu/gpu-kit.sh [KIT]`):
# unpacks the offline kit (gpu/gpu-offline-kit.sh; $1, default .gpu/site-py312.tar.xz) where the dataset
# stages' dependencies are missing, and puts the checkout on PYTHONPATH.
kit=${1:-.gpu/site-py312.tar.xz}
if [ -f "$kit" ] && ! python3 -c "import pybullet, trimesh, coacd, embreex, pydantic" 2>/dev/null; then
    mkdir -p /tmp/osgd-site && tar -xJf "$kit" -C /tmp/osgd-site
    export PYTHONPATH=/tmp/osgd-site:/tmp/osgd-site/_extra
fi
export PYTHONPATH=$PWD:${PYTHONPATH:-}
