"""Lists and describes a running HuMem server through gRPC server reflection,
with a client nobody in this project wrote: Python's `grpcio-reflection`,
which speaks only `grpc.reflection.v1alpha`.

    models/.venv/bin/python tools/reflection_check.py 127.0.0.1:50051

Prints the services the server lists, one per line, then for the HuMem
service each method as `METHOD(INPUT) -> OUTPUT`, then the fields of
`humem.v1.QueryRequest`. Exits non-zero when reflection fails; the end-to-end
test `reflection_v1alpha_lists_and_describes` runs it.
"""

import sys

import grpc
from google.protobuf.descriptor_pool import DescriptorPool
from grpc_reflection.v1alpha.proto_reflection_descriptor_database import (
    ProtoReflectionDescriptorDatabase,
)

SERVICE = "humem.v1.PlaceRecognition"
MESSAGE = "humem.v1.QueryRequest"


def main(address: str) -> None:
    with grpc.insecure_channel(address) as channel:
        database = ProtoReflectionDescriptorDatabase(channel)
        for name in database.get_services():
            print(f"service {name}")
        pool = DescriptorPool(database)
        service = pool.FindServiceByName(SERVICE)
        for method in service.methods:
            print(f"method {method.name}({method.input_type.full_name}) -> {method.output_type.full_name}")
        message = pool.FindMessageTypeByName(MESSAGE)
        for field in message.fields:
            print(f"field {MESSAGE}.{field.name} = {field.number}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: reflection_check.py HOST:PORT")
    main(sys.argv[1])
