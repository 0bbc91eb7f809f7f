// Job: HUMEM_API marks the library's exported classes and functions. The
// shared library is built with hidden visibility, so gRPC and protobuf
// symbols inside it never clash with a host application's own copies.
#ifndef HUMEM_EXPORT_H_
#define HUMEM_EXPORT_H_

#if defined(__GNUC__) || defined(__clang__)
#define HUMEM_API __attribute__((visibility("default")))
#else
#define HUMEM_API
#endif

#endif  // HUMEM_EXPORT_H_
