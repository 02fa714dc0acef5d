// The offscreen context: Mesa's OSMesa renders into memory on the CPU, so pictures need neither a
// display nor a GPU (CI, servers). Only binaries that link OSMesa's GL include this file.
#include "renderer.hpp"

#include <GL/osmesa.h>

namespace sinew::render {

Offscreen::Offscreen(int width, int height) : m_width(width), m_height(height) {
  if (width < 1 || height < 1 || width > 8192 || height > 8192)
    fail("offscreen image: ", width, " x ", height, " pixels (each side must be 1 to 8192)");
  m_context = OSMesaCreateContextExt(OSMESA_RGBA, 24, 8, 0, nullptr);
  if (!m_context) fail("offscreen image: OSMesa could not create a context");
  m_buffer.assign(static_cast<std::size_t>(width) * height * 4, 0);
  make_current();
}

Offscreen::~Offscreen() {
  if (m_context) OSMesaDestroyContext(static_cast<OSMesaContext>(m_context));
}

void Offscreen::make_current() {
  if (!OSMesaMakeCurrent(static_cast<OSMesaContext>(m_context), m_buffer.data(), GL_UNSIGNED_BYTE, m_width, m_height))
    fail("offscreen image: OSMesa could not make its context current");
}

std::vector<std::uint8_t> Offscreen::pixels() const { return read_pixels(m_width, m_height); }

}  // namespace sinew::render
