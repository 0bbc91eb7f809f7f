"""The protobuf messages and gRPC stub of humem.v1, generated from
proto/humem/v1/humem.proto by ../generate_stubs.py (do not edit them; run
the script after changing the .proto)."""
