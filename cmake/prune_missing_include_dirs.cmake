# Injected with -DCMAKE_PROJECT_INCLUDE=... when msg_defs/ is built with plain cmake inside a
# pip-installed ROS 2 prefix (the Makefile does this). The PyPI ROS wheels ship imported targets
# (std_msgs' Python typesupport among them) whose INTERFACE_INCLUDE_DIRECTORIES name directories
# of the machine that built the wheels; CMake refuses such targets at generate time. After the
# project has been configured, drop the entries that do not exist. A colcon build in a full ROS
# install never loads this file, so msg_defs/CMakeLists.txt stays the standard one.
function(_train_calib_prune_missing_include_dirs)
  get_property(_targets DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY IMPORTED_TARGETS)
  foreach(_target IN LISTS _targets)
    get_target_property(_dirs ${_target} INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT _dirs)
      continue()
    endif()
    set(_kept "")
    set(_changed FALSE)
    foreach(_dir IN LISTS _dirs)
      if(_dir MATCHES "^\\$<" OR EXISTS "${_dir}")
        list(APPEND _kept "${_dir}")
      else()
        set(_changed TRUE)
      endif()
    endforeach()
    if(_changed)
      set_target_properties(${_target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_kept}")
    endif()
  endforeach()
endfunction()
cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _train_calib_prune_missing_include_dirs)
