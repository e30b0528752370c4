# rclpy uses the C side of a message package alone: the C structs (rosidl_generator_c), the type
# supports rmw loads for them (rosidl_typesupport_c dispatching to the Fast DDS and introspection
# ones), the type description (type hashes) and the Python bindings (rosidl_generator_py). The
# C++ side (rosidl_generator_cpp and the three C++ type supports) is half of the compiling and
# has no user where ROS 2 comes from PyPI (no rclcpp wheel). rosidl has no switch for it: every
# generator found registers itself in AMENT_EXTENSIONS_rosidl_generate_idl_interfaces, which
# rosidl_generate_interfaces runs in turn. So the generators are found here, before the
# package's own find_package calls (ament's configs are included once per directory), and the
# C++ ones taken off that list.
find_package(rosidl_default_generators REQUIRED)
list(FILTER AMENT_EXTENSIONS_rosidl_generate_idl_interfaces EXCLUDE REGEX "_cpp:")
