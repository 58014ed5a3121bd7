# Included into the CMake build of crane_reference_interfaces by scripts/setup.sh and scripts/check_colcon.sh
# (CMAKE_PROJECT_INCLUDE), which build it against ROS 2 Jazzy's PyPI wheels in .venv.  Those wheels' CMake exports name the include directories
# of the machine that built them (/opt/python/cp3XX-cp3XX/...: Python's and NumPy's headers).  At the end of the
# configure step each such directory of an imported target becomes this Python's.  A ROS distribution needs none
# of this (colcon builds the package as it is).

if(CMAKE_VERSION VERSION_LESS 3.19)
  message(FATAL_ERROR "building against the PyPI ROS wheels needs CMake >= 3.19 (cmake_language(DEFER)); this is ${CMAKE_VERSION}")
endif()

function(_pypi_ros_local_include_directories)
  find_package(Python3 REQUIRED COMPONENTS Interpreter Development.Module NumPy)
  get_property(targets DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY IMPORTED_TARGETS)
  foreach(target IN LISTS targets)
    get_target_property(directories ${target} INTERFACE_INCLUDE_DIRECTORIES)
    if(directories)
      list(TRANSFORM directories REPLACE "^/opt/python/[^/]+/include/python3\\.[0-9]+$" "${Python3_INCLUDE_DIRS}")
      list(TRANSFORM directories REPLACE "^/opt/python/[^/]+/.*/numpy/_core/include$" "${Python3_NumPy_INCLUDE_DIRS}")
      set_target_properties(${target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${directories}")
    endif()
  endforeach()
endfunction()

cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _pypi_ros_local_include_directories)
