#!/usr/bin/env python3
"""Objects in an S3-compatible bucket, for the bench scripts (bench/sharded_bake.sh,
bench/serve_sources.sh), with boto3.

The endpoint and credentials come from the environment as for `terrastream`: AWS_ENDPOINT_URL,
AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY, AWS_REGION. URLs are s3://BUCKET/PREFIX.

Usage:
  s3_upload.py count s3://BUCKET/PREFIX          prints "OBJECTS BYTES" under the prefix (or of
                                                 the one object when PREFIX is its key)
  s3_upload.py compare s3://BUCKET/PREFIX DIR    the objects are DIR's files, byte for byte
                                                 (MD5 against a single-part ETag, else the bytes);
                                                 exit 1 naming the first differences
  s3_upload.py put FILE s3://BUCKET/KEY          uploads FILE as one object (multipart past
                                                 64 MiB); prints "SECONDS BYTES"
  s3_upload.py rm s3://BUCKET/PREFIX             deletes every object under the prefix; prints
                                                 how many
"""

import hashlib
import os
import sys
import time

import boto3
from boto3.s3.transfer import TransferConfig


def client():
    return boto3.client(
        "s3",
        endpoint_url=os.environ.get("AWS_ENDPOINT_URL"),
        region_name=os.environ.get("AWS_REGION", "us-east-1"),
    )


def split(url):
    if not url.startswith("s3://"):
        sys.exit(f"s3_upload.py: {url}: not an s3:// URL")
    bucket, _, prefix = url[len("s3://"):].partition("/")
    return bucket, prefix


def listing(s3, url):
    """(key relative to the prefix, size, ETag) of every object under url."""
    bucket, prefix = split(url)
    if prefix and not prefix.endswith("/"):
        prefix += "/"
    for page in s3.get_paginator("list_objects_v2").paginate(Bucket=bucket, Prefix=prefix):
        for o in page.get("Contents", []):
            yield o["Key"][len(prefix):], o["Size"], o["ETag"].strip('"')


def count(url):
    """An object's own key counts as one object; otherwise the objects under the prefix."""
    s3 = client()
    bucket, key = split(url)
    try:
        print(1, s3.head_object(Bucket=bucket, Key=key)["ContentLength"])
        return
    except s3.exceptions.ClientError:
        pass
    n = b = 0
    for _, size, _ in listing(s3, url):
        n += 1
        b += size
    print(n, b)


def compare(url, root):
    s3 = client()
    bucket, prefix = split(url)
    prefix = prefix.rstrip("/") + "/" if prefix else ""
    objects = {k: (size, etag) for k, size, etag in listing(s3, url)}
    files = {}
    for d, _, names in os.walk(root):
        for n in names:
            p = os.path.join(d, n)
            files[os.path.relpath(p, root).replace(os.sep, "/")] = p
    bad = []
    for k in sorted(set(files) - set(objects)):
        bad.append(f"missing object: {k}")
    for k in sorted(set(objects) - set(files)):
        bad.append(f"extra object: {k}")
    fetched = 0
    for k in sorted(set(files) & set(objects)):
        size, etag = objects[k]
        with open(files[k], "rb") as f:
            data = f.read()
        if len(data) != size:
            bad.append(f"{k}: {size} bytes in the bucket, {len(data)} in the directory")
        elif "-" not in etag and len(etag) == 32:
            if hashlib.md5(data).hexdigest() != etag:
                bad.append(f"{k}: MD5 differs")
        else:
            fetched += 1
            body = s3.get_object(Bucket=bucket, Key=prefix + k)["Body"].read()
            if body != data:
                bad.append(f"{k}: bytes differ")
    if bad:
        print(f"{len(bad)} differences, first: " + "; ".join(bad[:5]))
        sys.exit(1)
    print(f"identical: {len(files)} objects = {len(files)} files ({fetched} compared by bytes, the others by MD5)")


def put(path, url):
    bucket, key = split(url)
    size = os.path.getsize(path)
    t0 = time.monotonic()
    client().upload_file(path, bucket, key, Config=TransferConfig(multipart_threshold=64 << 20, multipart_chunksize=64 << 20))
    print(f"{time.monotonic() - t0:.2f} {size}")


def rm(url):
    s3 = client()
    bucket, prefix = split(url)
    prefix = prefix.rstrip("/") + "/" if prefix else ""
    keys = [prefix + k for k, _, _ in listing(s3, url)]
    for i in range(0, len(keys), 1000):
        s3.delete_objects(Bucket=bucket, Delete={"Objects": [{"Key": k} for k in keys[i:i + 1000]], "Quiet": True})
    print(len(keys))


def main():
    a = sys.argv[1:]
    cmds = {"count": (count, 1), "compare": (compare, 2), "put": (put, 2), "rm": (rm, 1)}
    if not a or a[0] not in cmds or len(a) != cmds[a[0]][1] + 1:
        sys.exit(__doc__)
    cmds[a[0]][0](*a[1:])


if __name__ == "__main__":
    main()
