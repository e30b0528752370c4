# Included after each package's project() (CMAKE_PROJECT_INCLUDE, set in CMakeLists.txt here).
include("${CMAKE_CURRENT_LIST_DIR}/c_side_only.cmake")
include("${CMAKE_CURRENT_LIST_DIR}/wheel_include_dirs.cmake")
