# Third-party dependencies. The core library needs only the standard library and threads; the
# header-only JSON and CLI libraries fall back to copies in third_party/ on machines without
# Debian's packages (the GPU machine), and ITK stays at the edge (src/io).

find_package(Threads REQUIRED)

# nlohmann-json: Debian's nlohmann-json3-dev, else the vendored copy of the same version.
find_package(nlohmann_json 3.10 QUIET)
if(NOT nlohmann_json_FOUND)
  add_library(nlohmann_json INTERFACE)
  target_include_directories(nlohmann_json SYSTEM INTERFACE
                             ${PROJECT_SOURCE_DIR}/third_party/nlohmann_json/include)
  add_library(nlohmann_json::nlohmann_json ALIAS nlohmann_json)
  message(STATUS "nlohmann-json: using third_party copy")
endif()

# CLI11: Debian's libcli11-dev, else the vendored copy.
find_package(CLI11 2.1 QUIET CONFIG)
if(NOT CLI11_FOUND)
  add_library(sonoslice_cli11 INTERFACE)
  target_include_directories(sonoslice_cli11 SYSTEM INTERFACE
                             ${PROJECT_SOURCE_DIR}/third_party/CLI11/include)
  add_library(CLI11::CLI11 ALIAS sonoslice_cli11)
  message(STATUS "CLI11: using third_party copy")
endif()

# pugixml: PLUS configuration XML (Debian's libpugixml-dev). Optional: without it
# read_plus_config throws "built without pugixml". pugixml >= 1.11 names its target
# pugixml::pugixml; older releases name it pugixml.
set(SONOSLICE_HAVE_PUGIXML OFF)
find_package(pugixml QUIET)
if(pugixml_FOUND)
  if(TARGET pugixml::pugixml)
    set(SONOSLICE_PUGIXML_TARGET pugixml::pugixml)
    set(SONOSLICE_HAVE_PUGIXML ON)
  elseif(TARGET pugixml)
    set(SONOSLICE_PUGIXML_TARGET pugixml)
    set(SONOSLICE_HAVE_PUGIXML ON)
  endif()
endif()
if(NOT SONOSLICE_HAVE_PUGIXML)
  message(STATUS "pugixml not found: PLUS configuration files cannot be read")
endif()

# find_package(<name> COMPONENTS ...) as the option <switch> asks: OFF skips it, AUTO uses it
# when found, ON requires it. Sets <result> ON when found. (A macro: the package's variables must
# land in the caller's scope.)
macro(sonoslice_find_optional name switch result)
  set(${result} OFF)
  if(NOT ${switch} STREQUAL "OFF")
    if(${switch} STREQUAL "AUTO")
      find_package(${name} QUIET COMPONENTS ${ARGN})
    else()
      find_package(${name} REQUIRED COMPONENTS ${ARGN})
    endif()
    if(${name}_FOUND)
      set(${result} ON)
    endif()
  endif()
endmacro()

# ITK: medical image formats.
sonoslice_find_optional(ITK SONOSLICE_WITH_ITK SONOSLICE_HAVE_ITK
  ITKCommon ITKIOImageBase ITKIONIFTI ITKIOMeta ITKIONRRD ITKIOGDCM ITKIOPNG ITKImageGrid
  ITKImageFunction ITKGDCM)  # ITKGDCM: GDCM itself, to check DICOM slices before ITK reads them
if(SONOSLICE_HAVE_ITK AND CMAKE_CXX_COMPILER_ID MATCHES "Clang")
  # Debian's ITK headers refuse clang; cmake/ItkClangCompat.h says why and works around it. Every
  # C++ source gets it (the library, the CLI, the tests, the fuzz harnesses).
  add_compile_options($<$<COMPILE_LANGUAGE:CXX>:-include${PROJECT_SOURCE_DIR}/cmake/ItkClangCompat.h>)
endif()

# libpng: PNG outputs (stacks, masks) are written with it directly, so that a failed write (a full
# disk) is reported; ITK's 2-D writer did not check. Debian's libpng-dev. Optional: without it
# PNG outputs are refused with "built without libpng".
find_package(PNG QUIET)
set(SONOSLICE_HAVE_PNG ${PNG_FOUND})
if(NOT SONOSLICE_HAVE_PNG)
  message(STATUS "libpng not found: PNG outputs are disabled")
endif()

# VTK: surface meshes.
sonoslice_find_optional(VTK SONOSLICE_WITH_VTK SONOSLICE_HAVE_VTK
  CommonCore CommonDataModel CommonExecutionModel IOLegacy IOXML IOGeometry IOPLY FiltersCore)

# GoogleTest: an installed package, else the sources Debian's googletest package puts in
# /usr/src/googletest (or any copy named by SONOSLICE_GTEST_SOURCE_DIR, e.g. carried to the GPU
# machine).
if(SONOSLICE_BUILD_TESTS)
  find_package(GTest QUIET)
  if(NOT GTest_FOUND)
    set(SONOSLICE_GTEST_SOURCE_DIR "/usr/src/googletest" CACHE PATH "GoogleTest sources")
    if(EXISTS "${SONOSLICE_GTEST_SOURCE_DIR}/CMakeLists.txt")
      set(INSTALL_GTEST OFF CACHE BOOL "" FORCE)
      add_subdirectory(${SONOSLICE_GTEST_SOURCE_DIR} ${CMAKE_BINARY_DIR}/googletest EXCLUDE_FROM_ALL)
      if(NOT TARGET GTest::gtest_main)  # GoogleTest >= 1.11 defines these itself
        add_library(GTest::gtest_main ALIAS gtest_main)
        add_library(GTest::gtest ALIAS gtest)
      endif()
    else()
      message(WARNING "GoogleTest not found: tests disabled")
      set(SONOSLICE_BUILD_TESTS OFF)
    endif()
  endif()
endif()

if(SONOSLICE_BUILD_BENCHMARKS)
  find_package(benchmark QUIET)
  if(NOT benchmark_FOUND)
    message(STATUS "Google Benchmark not found: bench/ programs disabled")
    set(SONOSLICE_BUILD_BENCHMARKS OFF)
  endif()
endif()
