#include "server/eval/eval.h"

#include <gtest/gtest.h>

namespace exo::eval {
namespace {

TEST(EvalTest, Placeholder) { SUCCEED(); }

}  // namespace
}  // namespace exo::eval
