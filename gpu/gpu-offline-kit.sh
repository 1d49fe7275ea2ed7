#!/usr/bin/env bash
# The offline install kit of gpu/table-gpu.sh and gpu/gpu-kit.sh: the dataset stages' dependencies that a GPU
# image with torch, numpy, scipy, pyarrow, typer, opencv and matplotlib lacks, as one stripped site-packages
# tarball, for a machine with no network. Run it where pip reaches PyPI:
#
#   gpu/gpu-offline-kit.sh [PYTHON_VERSION]      # default 3.12; writes .gpu/site-py<version>.tar.xz
#
# Official pybullet wheels stop at CPython 3.11; for 3.12 the kit takes pybullet-arm64 3.2.8, a rebuild of the
# same Bullet sources that installs the same `pybullet` module. Debug symbols are stripped, and pybullet's
# example data and environments, which osgd never uses, are left out.
set -euo pipefail
cd "$(dirname "$0")/.."
VERSION=${1:-3.12}
TAG=${VERSION/./}
KIT=${KIT:-.gpu}
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
PYBULLET="pybullet==3.2.7"
[ "$VERSION" != "3.11" ] && PYBULLET="pybullet-arm64==3.2.8"
PACKAGES=("$PYBULLET" trimesh==5.2.0 embreex==4.4.0.post1 manifold3d==3.5.4 rtree==1.4.1 shapely==2.2.0
          coacd==1.0.14 pydantic==2.14.3 pydantic-core==2.50.4 annotated-types==0.8.0 typing-inspection==0.4.5)
PLATFORMS=()
for platform in manylinux_2_28_x86_64 manylinux_2_27_x86_64 manylinux_2_24_x86_64 manylinux_2_17_x86_64 \
                manylinux2014_x86_64 manylinux1_x86_64; do PLATFORMS+=(--platform "$platform"); done
python3 -m pip download -q --no-deps --only-binary=:all: --python-version "$VERSION" --implementation cp \
    "${PLATFORMS[@]}" -d "$WORK/wheels" "${PACKAGES[@]}"
# pydantic-core needs typing_extensions >= 4.14 (Sentinel): a copy off the path, under _extra
python3 -m pip download -q --no-deps --only-binary=:all: -d "$WORK/extra" typing-extensions==4.16.0
mkdir -p "$WORK/site/_extra"
for wheel in "$WORK"/wheels/*.whl; do python3 -m zipfile -e "$wheel" "$WORK/site"; done
python3 -m zipfile -e "$WORK"/extra/*.whl "$WORK/site/_extra"
rm -rf "$WORK"/site/{pybullet_data,pybullet_envs,pybullet_examples,pybullet_robots,pybullet_utils,shapely/tests}
find "$WORK/site" -name '*.so*' -type f -exec strip --strip-unneeded {} + 2>/dev/null || true
mkdir -p "$KIT"
tar -C "$WORK/site" -cJf "$KIT/site-py$TAG.tar.xz" .
echo "wrote $KIT/site-py$TAG.tar.xz ($(du -h "$KIT/site-py$TAG.tar.xz" | cut -f1)); gpu/table-gpu.sh unpacks it"
