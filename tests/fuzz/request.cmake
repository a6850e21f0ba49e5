# fuzz_request: libFuzzer target for the server's request handling (request_validation +
# ExtractJob, no gRPC). Included by tests/fuzz/CMakeLists.txt; needs the service
# (-DTANDEM_BUILD_SERVICE=ON, tests/sanitize.sh's default).
# The service libraries the target exercises are instrumented like tandem_core (coverage +
# ASan + UBSan); gRPC, protobuf and Draco themselves are system libraries, not instrumented.
if(NOT TARGET tandem_server_lib)
  message(STATUS "fuzz_request skipped: needs -DTANDEM_BUILD_SERVICE=ON")
  return()
endif()
if(NOT DEFINED TANDEM_SANITIZE)
  set(TANDEM_SANITIZE -fsanitize=address,undefined -fno-sanitize-recover=all
                      -fno-omit-frame-pointer -g)
endif()
foreach(lib tandem_server_lib tandem_service_common tandem_codec)
  target_compile_options(${lib} PRIVATE -fsanitize=fuzzer-no-link ${TANDEM_SANITIZE})
endforeach()
add_executable(fuzz_request ${CMAKE_CURRENT_LIST_DIR}/fuzz_request.cc)
target_compile_options(fuzz_request PRIVATE -fsanitize=fuzzer ${TANDEM_SANITIZE})
target_link_options(fuzz_request PRIVATE -fsanitize=fuzzer ${TANDEM_SANITIZE})
target_link_libraries(fuzz_request PRIVATE tandem_server_lib tandem_codec tandem_proto)
