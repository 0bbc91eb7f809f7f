# HuMem place recognition for ORB-SLAM3 v1.0: compiles VprKeyFrameDatabase
# into libORB_SLAM3 and links it with the HuMem C++ client.
#
# Included by ORB-SLAM3's CMakeLists.txt once orbslam3-v1.0.patch is applied:
#   cmake .. -DCMAKE_BUILD_TYPE=Release \
#            -DORB_SLAM3_PLUGIN=/path/to/humem/client-cpp/orbslam3/orbslam3-humem.cmake \
#            -DCMAKE_PREFIX_PATH="/path/to/humem-client-prefix;/path/to/pangolin-prefix"
# It runs right after the ORB_SLAM3 library target is defined (PROJECT_NAME).
# The plugin is compiled with ORB-SLAM3's own flags (-std=c++11 -march=native),
# which it must share with libORB_SLAM3 for Eigen's alignment to agree.

find_package(humem_client REQUIRED)

target_sources(${PROJECT_NAME} PRIVATE ${CMAKE_CURRENT_LIST_DIR}/VprKeyFrameDatabase.cc)
target_include_directories(${PROJECT_NAME} PUBLIC ${CMAKE_CURRENT_LIST_DIR})
# ORB-SLAM3 uses the plain target_link_libraries signature: keep to it.
target_link_libraries(${PROJECT_NAME} humem::client)

message(STATUS "ORB-SLAM3 HuMem plugin: ${CMAKE_CURRENT_LIST_DIR}/VprKeyFrameDatabase.cc, humem_client ${humem_client_VERSION} (${humem_client_DIR})")
