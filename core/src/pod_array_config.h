// TANDEM_POD_MAP: 1 where PodArray maps its large blocks (Linux), 0 where every block stays
// on the heap: other systems, and AddressSanitizer builds, where the heap's redzones catch
// overflows (gcc says so with __SANITIZE_ADDRESS__, clang with __has_feature).
#ifndef TANDEM_POD_ARRAY_CONFIG_H_
#define TANDEM_POD_ARRAY_CONFIG_H_

#if defined(__SANITIZE_ADDRESS__)
#define TANDEM_POD_ASAN 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define TANDEM_POD_ASAN 1
#endif
#endif

#if defined(__linux__) && !defined(TANDEM_POD_ASAN)
#define TANDEM_POD_MAP 1
#else
#define TANDEM_POD_MAP 0
#endif

#endif  // TANDEM_POD_ARRAY_CONFIG_H_
