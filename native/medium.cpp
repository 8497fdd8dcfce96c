#include "medium.h"

#include <sstream>
#include <stdexcept>

#include "spectrum.h"

namespace ep {

Float Medium::mua_at(Float lambda_nm) const { return mua_table ? mua_table->eval(lambda_nm) : mua; }
Float Medium::mus_at(Float lambda_nm) const { return mus_table ? mus_table->eval(lambda_nm) : mus; }

namespace {
[[noreturn]] void fail(const std::string& owner, const char* field, Float value, const char* rule) {
    std::ostringstream os;
    os.precision(17);
    os << owner << ": medium." << field << " = " << value << " " << rule;
    throw std::invalid_argument(os.str());
}
}  // namespace

void Medium::validate(const std::string& owner) const {
    if (!std::isfinite(mua) || mua < 0) fail(owner, "mua", mua, "must be a finite number >= 0 (cm^-1)");
    if (!std::isfinite(mus) || mus < 0) fail(owner, "mus", mus, "must be a finite number >= 0 (cm^-1)");
    if (!std::isfinite(g) || g < -1 || g > 1) fail(owner, "g", g, "must be in [-1, 1]");
    if (!std::isfinite(n) || n < 1) fail(owner, "n", n, "must be a finite number >= 1");
}

}  // namespace ep
