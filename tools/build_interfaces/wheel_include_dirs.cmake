# The ROS 2 message wheels on PyPI export, in their <package>__rosidl_generator_py targets, the
# Python and NumPy include folders of the machine the wheels were built on
# (/opt/python/cp311-cp311/include/python3.11, that machine's numpy/_core/include), and CMake
# refuses a target whose include folders do not exist. Included after each package's project()
# (each_package.cmake), this points those two at this interpreter's and this NumPy's include
# folders once the package's directory is processed, every find_package done: the wheels' own
# files are left as they are.
function(_use_this_pythons_include_dirs)
  get_property(targets DIRECTORY PROPERTY IMPORTED_TARGETS)
  foreach(target IN LISTS targets)
    get_target_property(dirs ${target} INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT dirs)
      continue()
    endif()
    set(fixed "")
    foreach(dir IN LISTS dirs)
      if(NOT EXISTS "${dir}" AND dir MATCHES "/include/python3\\.[0-9]+$" AND Python3_INCLUDE_DIRS)
        set(dir "${Python3_INCLUDE_DIRS}")
      elseif(NOT EXISTS "${dir}" AND dir MATCHES "/numpy/(_core|core)/include$"
          AND Python3_NumPy_INCLUDE_DIRS)
        set(dir "${Python3_NumPy_INCLUDE_DIRS}")
      endif()
      list(APPEND fixed "${dir}")
    endforeach()
    if(NOT fixed STREQUAL dirs)
      set_property(TARGET ${target} PROPERTY INTERFACE_INCLUDE_DIRECTORIES "${fixed}")
    endif()
  endforeach()
endfunction()
cmake_language(DEFER CALL _use_this_pythons_include_dirs)
