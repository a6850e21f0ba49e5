// The encoding step both codec front ends share (draco_codec.cc, neuroglancer_draco.cc).
#ifndef TANDEM_CODEC_DRACO_ENCODE_H_
#define TANDEM_CODEC_DRACO_ENCODE_H_

#include <string>

#include "absl/status/statusor.h"
#include "draco/compression/encode.h"
#include "draco/mesh/mesh.h"

namespace tandem::codec {

// `encoder` (its attributes' quantization set, or none) at `level`: 0 = sequential coding,
// 1..10 = Edgebreaker at speed 10 - level. Internal if Draco fails.
absl::StatusOr<std::string> EncodeMeshAtLevel(draco::Encoder& encoder, const draco::Mesh& mesh,
                                              int level);

}  // namespace tandem::codec

#endif  // TANDEM_CODEC_DRACO_ENCODE_H_
