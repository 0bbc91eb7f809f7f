// Job: the one header to include for the whole client library.
#ifndef HUMEM_HUMEM_H_
#define HUMEM_HUMEM_H_

#include "humem/image_cache.h"
#include "humem/keyframe_registry.h"
#include "humem/status.h"
#include "humem/types.h"
#include "humem/vpr_client.h"

#endif  // HUMEM_HUMEM_H_
