#!/usr/bin/python3
"""Lists the gRPC services of a running exoview_server through server reflection
(grpc.reflection.v1alpha, what grpcurl uses), with the methods of each service as the server
describes them. Prints one JSON line: {"services": {"exoview.v1.Exoview": ["GetStats", ...], ...}} (null where
the server has no descriptor for a listed service).

  list_services.py --target=127.0.0.1:50051
"""
import argparse
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import exoview_stubs  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--target", default="127.0.0.1:50051", help="server address host:port")
    ap.add_argument("--stubs", help="directory of the generated stubs (default: generate them)")
    args = ap.parse_args()
    exoview_stubs.load(args.stubs)
    import grpc
    import grpc_reflection_v1alpha_pb2 as rpb
    import grpc_reflection_v1alpha_pb2_grpc as rpb_grpc
    from google.protobuf import descriptor_pb2

    stub = rpb_grpc.ServerReflectionStub(grpc.insecure_channel(args.target))

    def ask(request):
        (response,) = list(stub.ServerReflectionInfo(iter([request]), timeout=10))
        return response

    try:
        listed = ask(rpb.ServerReflectionRequest(list_services="*"))
        if listed.HasField("error_response"):
            print("list_services: %s" % listed.error_response.error_message, file=sys.stderr)
            return 1
        services = {}
        for s in listed.list_services_response.service:
            # null = the server lists the service but has no descriptor for it (gRPC's built-in
            # health service is not a generated protobuf service in C++).
            methods = None
            files = ask(rpb.ServerReflectionRequest(file_containing_symbol=s.name))
            for blob in files.file_descriptor_response.file_descriptor_proto:
                fd = descriptor_pb2.FileDescriptorProto.FromString(blob)
                for svc in fd.service:
                    if (fd.package + "." if fd.package else "") + svc.name == s.name:
                        methods = sorted(m.name for m in svc.method)
            services[s.name] = methods
    except grpc.RpcError as e:
        print("list_services: %s: %s" % (e.code().name, e.details()), file=sys.stderr)
        return 1
    print(json.dumps({"services": services}, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
