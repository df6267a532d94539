# Injected by build.sh with -DCMAKE_PROJECT_INCLUDE=<this file>; runs right after project().
#
# The ROS 2 PyPI wheels were built in a manylinux container whose Python lived in
# /opt/python/cp311-cp311. Their exported CMake targets <pkg>::<pkg>__rosidl_generator_py
# still name that interpreter's include dir and numpy's include dir, which do not exist
# here, and CMake refuses to generate ("includes non-existent path"). Instead of patching
# the installed wheels, rewrite those paths on every imported target once the whole
# CMakeLists.txt has been read (cmake_language(DEFER), CMake >= 3.19).

set(_WHEEL_BUILD_PYTHON_PREFIX "/opt/python/cp311-cp311" CACHE STRING
  "Python prefix of the machine that built the ROS wheels (found in their exported targets)")

function(_wheel_prefix_fixup)
  find_package(Python3 REQUIRED COMPONENTS Interpreter Development.Module NumPy)
  get_property(_targets DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY IMPORTED_TARGETS)
  set(_fixed 0)
  foreach(_t IN LISTS _targets)
    get_target_property(_type ${_t} TYPE)
    get_target_property(_inc ${_t} INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT _inc)
      continue()
    endif()
    set(_new "")
    set(_changed FALSE)
    foreach(_d IN LISTS _inc)
      if(_d MATCHES "^${_WHEEL_BUILD_PYTHON_PREFIX}/include/python")
        list(APPEND _new ${Python3_INCLUDE_DIRS})
        set(_changed TRUE)
      elseif(_d MATCHES "^${_WHEEL_BUILD_PYTHON_PREFIX}/.*numpy/_?core/include$")
        list(APPEND _new ${Python3_NumPy_INCLUDE_DIRS})
        set(_changed TRUE)
      elseif(_d MATCHES "^${_WHEEL_BUILD_PYTHON_PREFIX}/")
        set(_changed TRUE)  # any other path of the wheel builder: drop it
      else()
        list(APPEND _new "${_d}")
      endif()
    endforeach()
    if(_changed)
      list(REMOVE_DUPLICATES _new)
      set_target_properties(${_t} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_new}")
      math(EXPR _fixed "${_fixed} + 1")
    endif()
  endforeach()
  message(STATUS "wheel_prefix_fixup: rewrote ${_WHEEL_BUILD_PYTHON_PREFIX} include dirs on ${_fixed} imported targets")
endfunction()

cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _wheel_prefix_fixup)
